"""Phase 1 of an import: files to ConvertedGrids (kernels.pipeline), no Blender data touched.
Single files (importer.py) and sequences (sequence_import.py) both convert through here, so an
import refuses the same grids and reports progress the same way whichever it is.

The options are a ``kernels.convert_options.ConvertOptions``; an import adds its own limit: grids
whose index coordinates float32 attributes cannot hold exactly are refused (schema.ORIGIN_LIMIT).
"""

import os

from ...kernels import pipeline
from ...kernels.convert_options import DEFAULTS

VDBImportError = pipeline.ConversionError  # an import failed; nothing was created
ImportCancelled = pipeline.ConversionCancelled


def bpy_abspath(path) -> str:
    if not path:
        return ""
    try:
        import bpy

        return os.path.abspath(bpy.path.abspath(path))
    except ImportError:
        return os.path.abspath(path)


def import_options(options):
    """``options`` as an import converts with them: index coordinates limited to what the
    point cloud's float32 attributes hold exactly."""
    from .schema import ORIGIN_LIMIT

    return options.replace(index_limit=ORIGIN_LIMIT)


def ahead_jobs(options) -> list:
    """The warm-up jobs an import in background mode (a script, ``blender -b``) gives a second
    process, to compile beside its reader and LODs: on a new cache (no LOD kernel cached: an
    install, an update) the field error, when asked, which the import then loads; and the render
    kernels of the scene's mode not compiled yet (a batch job's import is followed by its
    render, which then waits for what is left). Giving that process the LODs' kernels too made
    the import at most 1 s faster and the render after it 6 s slower (README, Cold start)."""
    from ...kernels import warmup
    from ..engine import kernel_cache

    jobs = ["error"] if options.compute_error and options.lods and not kernel_cache.compiled("lod") else []
    try:
        import bpy

        mode = bpy.context.scene.gaussvdb.mode.lower()
    except (ImportError, AttributeError):  # no scene (a restricted context)
        return jobs
    return jobs + warmup.missing(warmup.jobs_for(modes=(mode,), general=False))


def convert_steps(filepath, options=DEFAULTS, skipped=None):
    """kernels.pipeline.convert_steps for an import (import_options), its last step creating
    the objects."""
    from ..engine import kernel_cache, warmup_service

    kernel_cache.announce("vdb", "lod")
    warmup_service.compile_ahead(ahead_jobs(options))  # background mode only
    out = yield from pipeline.convert_steps(filepath, import_options(options), skipped,
                                            warmup_service.ready)
    yield 1.0, "creating objects"
    return out


class Progress:
    """Adapts a WindowManager (progress_begin/update/end) or a callable(fraction, text)."""

    def __init__(self, target):
        self.target = target
        self.wm = target if hasattr(target, "progress_update") else None
        if self.wm is not None:
            try:
                self.wm.progress_begin(0, 1000)
            except Exception:  # noqa: BLE001 - no window (some headless contexts)
                self.wm = None

    def __call__(self, fraction, text):
        if self.wm is not None:
            try:
                self.wm.progress_update(int(1000 * fraction))
            except Exception:  # noqa: BLE001
                pass
        elif callable(self.target):
            self.target(fraction, text)

    def end(self):
        if self.wm is not None:
            try:
                self.wm.progress_end()
            except Exception:  # noqa: BLE001
                pass


def convert_file(filepath, options=DEFAULTS, progress=None, cancel=None, skipped=None) -> list:
    """Read and convert one file for an import. Raises VDBImportError/ImportCancelled."""
    steps = convert_steps(filepath, options, skipped)
    report = Progress(progress) if progress is not None else None
    try:
        return pipeline.run(steps, report, cancel)
    finally:
        if report is not None:
            report.end()
