"""Index-to-world maps stored in a grid's transform, as float64 4x4 column-vector matrices."""

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
    m = np.eye(4)
    if kind in _VEC3_COUNT:
        v = cur.array("<f8", 3 * _VEC3_COUNT[kind], "transform").reshape(-1, 3)
        if kind == "TranslationMap":
            m[:3, 3] = v[0]
        elif kind.endswith("TranslateMap"):
            m[:3, 3] = v[0]
            m[[0, 1, 2], [0, 1, 2]] = v[1]
        else:
            m[[0, 1, 2], [0, 1, 2]] = v[0]
    elif kind in ("AffineMap", "UnitaryMap"):
        # Mat4d in OpenVDB's row-vector convention (translation in the last row): transpose.
        m = cur.array("<f8", 16, "transform").reshape(4, 4).T.copy()
    elif kind == "NonlinearFrustumMap":
        raise cur.error("frustum transforms (NonlinearFrustumMap) are not supported: "
                        "the map is not affine", start)
    else:
        raise cur.error(f"unknown transform map type {kind!r}", start)
    if not np.all(np.isfinite(m)):
        raise cur.error("transform holds non-finite numbers", start)
    return m, kind
