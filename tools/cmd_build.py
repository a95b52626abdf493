"""`./gaussvdb build`: the installable extension zips, one per platform.

The wheels listed in blender_manifest.toml are fetched unmodified from PyPI into wheels/, then
Blender's own `blender_ext.py build --split-platforms` packs the zips and `validate` checks each.
`--platform` and `--python` build a subset (the tests build linux-x64 for the running Python).
cp311 wheels serve Blender 4.5-5.0, cp313 wheels 5.1 and later.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tomllib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"

# Wheel platform tag -> Blender platform name.
PLATFORM_OF_TAG = (("manylinux", "linux-x64"), ("macosx", None), ("win_amd64", "windows-x64"))
WHEEL_RE = re.compile(r"^(?P<name>[^-]+)-(?P<version>[^-]+)-(?P<py>cp\d+)-(?P<abi>[^-]+)-(?P<plat>.+)\.whl$")


def blender_platform(plat_tag: str) -> str:
    if plat_tag.startswith("macosx"):
        return "macos-arm64" if plat_tag.endswith("arm64") else "macos-x64"
    for prefix, name in PLATFORM_OF_TAG:
        if plat_tag.startswith(prefix):
            return name
    raise ValueError(f"unknown wheel platform tag {plat_tag!r}")


def blender_ext_script() -> str:
    import importlib.util

    # Located inside the bpy wheel without importing bpy: the CLI runs on plain Python.
    base = importlib.util.find_spec("bpy").submodule_search_locations[0]
    version_dir = next(d for d in os.listdir(base) if re.fullmatch(r"\d+\.\d+", d))
    return os.path.join(base, version_dir, "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")


def parse_wheels(manifest: dict) -> list[dict]:
    out = []
    for rel in manifest.get("wheels", []):
        m = WHEEL_RE.match(os.path.basename(rel))
        if not m:
            raise ValueError(f"{MANIFEST}: cannot parse wheel name {rel!r}")
        info = m.groupdict()
        info["rel"] = rel
        info["platform"] = blender_platform(info["plat"])
        out.append(info)
    return out


def fetch_wheel(wheel: dict, dest: str) -> None:
    path = os.path.join(dest, os.path.basename(wheel["rel"]))
    if os.path.exists(path):
        return
    cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
           "--python-version", wheel["py"][2:], "--implementation", "cp", "-d", dest,
           f"{wheel['name']}=={wheel['version']}"]
    for tag in wheel["plat"].split("."):
        cmd += ["--platform", tag]
    subprocess.run(cmd, check=True)
    if not os.path.exists(path):
        raise RuntimeError(f"pip did not produce {os.path.basename(path)}")


def stage_source(selected: list[dict], platforms: list[str], stage: str) -> None:
    """Copy the extension source with a manifest that names only the selected wheels."""
    shutil.rmtree(stage, ignore_errors=True)
    ignore = shutil.ignore_patterns(".git", ".venv*", "wheels", "dist", "build", "__pycache__",
                                    ".pytest_cache", ".ruff_cache", ".hypothesis")
    shutil.copytree(ROOT, stage, ignore=ignore, symlinks=False)
    os.makedirs(os.path.join(stage, "wheels"))
    for w in selected:
        shutil.copy2(os.path.join(ROOT, "wheels", os.path.basename(w["rel"])), os.path.join(stage, "wheels"))
    with open(os.path.join(ROOT, MANIFEST), encoding="utf-8") as f:
        text = f.read()
    wheels_toml = "wheels = [\n" + "".join(f'  "{w["rel"]}",\n' for w in selected) + "]"
    text = re.sub(r"(?ms)^wheels = \[.*?^\]", lambda _: wheels_toml, text)
    text = re.sub(r"(?m)^platforms = .*$", lambda _: "platforms = " + str(platforms).replace("'", '"'), text)
    with open(os.path.join(stage, MANIFEST), "w", encoding="utf-8") as f:
        f.write(text)


def build(platforms=None, pythons=None, out_dir=None) -> list[str]:
    with open(os.path.join(ROOT, MANIFEST), "rb") as f:
        manifest = tomllib.load(f)
    platforms = platforms or manifest["platforms"]
    selected = [w for w in parse_wheels(manifest)
                if w["platform"] in platforms and (not pythons or w["py"] in pythons)]
    wheel_dir = os.path.join(ROOT, "wheels")
    os.makedirs(wheel_dir, exist_ok=True)
    for i, w in enumerate(selected, 1):
        print(f"[{i}/{len(selected)}] wheel {os.path.basename(w['rel'])}", flush=True)
        fetch_wheel(w, wheel_dir)
    out_dir = os.path.abspath(out_dir or os.path.join(ROOT, "dist"))
    os.makedirs(out_dir, exist_ok=True)
    stage = os.path.join(ROOT, "build", "stage")
    stage_source(selected, platforms, stage)
    script = blender_ext_script()
    subprocess.run([sys.executable, script, "build", "--split-platforms", "--source-dir", stage,
                    "--output-dir", out_dir], check=True)
    prefix = f"{manifest['id']}-{manifest['version']}-"
    zips = sorted(os.path.join(out_dir, z) for z in os.listdir(out_dir)
                  if z.startswith(prefix) and z.endswith(".zip") and z[len(prefix):-4].replace("_", "-") in platforms)
    for z in zips:
        subprocess.run([sys.executable, script, "validate", z], check=True)
    return zips


def main(argv: list[str]) -> int:
    with open(os.path.join(ROOT, MANIFEST), "rb") as f:
        manifest = tomllib.load(f)
    pythons = sorted({w["py"] for w in parse_wheels(manifest)})
    parser = cli_errors.ArgumentParser(prog="gaussvdb build", description=__doc__,
                                       formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--platform", action="append", choices=manifest["platforms"],
                        help="one of the manifest's platforms (default: all)")
    parser.add_argument("--python", action="append", choices=pythons,
                        help=f"{' or '.join(pythons)} (default: all)")
    parser.add_argument("--out", help="output folder (default dist/)")
    args = parser.parse_args(argv)
    for z in build(args.platform, args.python, args.out):
        print(f"built and validated {os.path.relpath(z)}")
    return 0
