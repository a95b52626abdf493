"""Index-to-world maps stored in a grid's transform, as float64 4x4 column-vector matrices."""

import struct

import numpy as np

# Map type name -> number of Vec3d stored after it (see openvdb/math/Maps.h read()).
_VEC3_COUNT = {
    "UniformScaleMap": 5,          # scale, voxelSize, inverse, invScaleSqr, invTwiceScale
    "ScaleMap": 5,
    "UniformScaleTranslateMap": 6,  # translation first, then the five ScaleMap vectors
    "ScaleTranslateMap": 6,
    "TranslationMap": 1,
}


def read_transform(cur):
    """Read one map and return (4x4 float64 index_to_world, map type name).

    Raises VDBFormatError for a frustum map: it is not affine, so no 4x4 can stand for it.
    """
    start = cur.pos
    kind = cur.string("transform map type", limit=256)
    nvec = _VEC3_COUNT.get(kind)
    if nvec is not None:
        cur.need(24 * nvec, "transform")  # plain struct reads: numpy calls cost more than the maths
        v = struct.unpack_from(f"<{3 * nvec}d", cur.buf, cur.pos)
        cur.pos += 24 * nvec
        if kind == "TranslationMap":
            t, d = v[0:3], (1.0, 1.0, 1.0)
        elif kind.endswith("TranslateMap"):
            t, d = v[0:3], v[3:6]
        else:
            t, d = (0.0, 0.0, 0.0), v[0:3]
        m = np.array([[d[0], 0, 0, t[0]], [0, d[1], 0, t[1]], [0, 0, d[2], t[2]], [0, 0, 0, 1.0]])
    elif kind in ("AffineMap", "UnitaryMap"):
        # Mat4d in OpenVDB's row-vector convention (translation in the last row): transpose.
        m = cur.array("<f8", 16, "transform").reshape(4, 4).T.copy()
    elif kind == "NonlinearFrustumMap":
        raise cur.error("frustum transforms (NonlinearFrustumMap) are not supported: "
                        "the map is not affine", start)
    else:
        raise cur.error(f"unknown transform map type {kind!r}", start)
    if not np.isfinite(m).all():
        raise cur.error("transform holds non-finite numbers", start)
    return m, kind
