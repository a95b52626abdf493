/* reference mode (cpu.pieces.reference_piece): the leaf walk of every object, pieces between
 * the merged cell boundaries, trilinear voxel samples at midpoints from the brick atlas, exact
 * exponential compositing; objects overlapping in a piece add extinction; level-set surfaces:
 * first sign change + bisection, shaded in write_output. Lit volumes: Blinn-Phong on the voxels'
 * gradient (common.glsl's shade_sample, shadows from the frame's shadow grids).
 * Tables: atlas (3-D), cells, node_table, node_cells, cell_skip; atlas_sx, atlas_sy. */

ivec3 brick_base(int cid)
{
  return ivec3(cid % atlas_sx, (cid / atlas_sx) % atlas_sy, cid / (atlas_sx * atlas_sy)) * BRICK;
}

float vox(ivec3 base, int i, int j, int k)
{
  return texelFetch(atlas, base + ivec3(i, j, k), 0).r;
}

/* index point -> coordinates in its leaf's brick, clamped (brick_xyz) */
vec3 brick_xyz(int cid, vec3 x)
{
  vec3 c = texel(cells, cid).xyz;
  return clamp(x - (c * float(LEAF) - 1.0), 0.0, BRICK_HI);
}

float trilinear(ivec3 base, vec3 f)
{
  ivec3 i0 = ivec3(f);
  vec3 a = f - vec3(i0);
  int i = i0.x, j = i0.y, k = i0.z;
  float c00 = vox(base, i, j, k) * (1.0 - a.x) + vox(base, i + 1, j, k) * a.x;
  float c10 = vox(base, i, j + 1, k) * (1.0 - a.x) + vox(base, i + 1, j + 1, k) * a.x;
  float c01 = vox(base, i, j, k + 1) * (1.0 - a.x) + vox(base, i + 1, j, k + 1) * a.x;
  float c11 = vox(base, i, j + 1, k + 1) * (1.0 - a.x) + vox(base, i + 1, j + 1, k + 1) * a.x;
  return (c00 * (1.0 - a.y) + c10 * a.y) * (1.0 - a.z) + (c01 * (1.0 - a.y) + c11 * a.y) * a.z;
}

/* central differences of the voxels, interpolated trilinearly (trilinear_grad) */
vec3 trilinear_grad(ivec3 base, vec3 f)
{
  ivec3 i0 = ivec3(f);
  vec3 a = f - vec3(i0);
  vec3 g = vec3(0.0);
  for (int di = 0; di < 2; di++) {
    for (int dj = 0; dj < 2; dj++) {
      for (int dk = 0; dk < 2; dk++) {
        int i = i0.x + di, j = i0.y + dj, k = i0.z + dk;
        float w = (di == 1 ? a.x : 1.0 - a.x) * (dj == 1 ? a.y : 1.0 - a.y) * (dk == 1 ? a.z : 1.0 - a.z);
        int ia = max(i - 1, 0), ib = min(i + 1, 9), ja = max(j - 1, 0), jb = min(j + 1, 9);
        int ka = max(k - 1, 0), kb = min(k + 1, 9);
        g.x += w * (vox(base, ib, j, k) - vox(base, ia, j, k)) / float(ib - ia);
        g.y += w * (vox(base, i, jb, k) - vox(base, i, ja, k)) / float(jb - ja);
        g.z += w * (vox(base, i, j, kb) - vox(base, i, j, ka)) / float(kb - ka);
      }
    }
  }
  return g;
}

/* surfaces' previous sample per object: phi, t (t NaN: none yet) */
float sp_phi[MAX_OBJ];
float sp_t[MAX_OBJ];

/* the hit t where object ob's signed distance first turns <= 0 (sdf_crossing) */
float sdf_crossing(int ob, float phi, float t, float p0, float h, int cid)
{
  float tp = sp_t[ob], pp = sp_phi[ob];
  sp_phi[ob] = phi;
  sp_t[ob] = t;
  if (phi > 0.0) {
    return INF;
  }
  if (isnan(tp)) {
    return p0;
  }
  if (!(pp > 0.0)) {
    return INF;
  }
  float lo = max(tp, p0 - h), hi = t;
  ivec3 base = brick_base(cid);
  for (int it = 0; it < 30; it++) {
    float mid = 0.5 * (lo + hi);
    if (trilinear(base, brick_xyz(cid, g_ro[ob] + mid * g_rd[ob])) > 0.0) {
      lo = mid;
    }
    else {
      hi = mid;
    }
  }
  return 0.5 * (lo + hi);
}

int cov_obj[MAX_OBJ];
int cov_cell[MAX_OBJ];
ivec3 cov_base[MAX_OBJ]; /* the cover's brick in the atlas */
vec3 cov_org[MAX_OBJ]; /* index point of its brick's voxel 0 */

/* a piece [p0, p1] covered by ncov leaves: its sample count n and step h (and the covers'
 * bricks) */
void piece_start(float p0, float p1, int ncov, out int n, out float h)
{
  float dt = INF;
  for (int c = 0; c < ncov; c++) {
    int ob = cov_obj[c];
    dt = min(dt, obj_at(ob, OBJ_STEP) / length(g_rd[ob]));
    cov_base[c] = brick_base(cov_cell[c]);
    cov_org[c] = texel(cells, cov_cell[c]).xyz * float(LEAF) - 1.0;
  }
  n = max(1, int(ceil((p1 - p0) / dt)));
  h = (p1 - p0) / float(n);
}

/* the piece's sample at t (midpoint of a step h); returns true when the ray ends */
bool reference_sample(inout State st, Ray r, float t, float p0, float h, int ncov)
{
  float sig = 0.0, vs = 0.0, vw = 0.0;
  vec3 col = vec3(0.0);
  int best = -1;
  float bt = INF;
  for (int c = 0; c < ncov; c++) {
    int ob = cov_obj[c], cid = cov_cell[c];
    vec3 x = g_ro[ob] + t * g_rd[ob];
    float val = trilinear(cov_base[c], clamp(x - cov_org[c], 0.0, BRICK_HI));
    int kind = g_kind[ob];
    if (kind == KIND_SURFACE) {
      float th = sdf_crossing(ob, val, t, p0, h, cid);
      if (th < bt) {
        bt = th;
        best = c;
      }
      continue;
    }
    if (kind == KIND_SHELL) { /* SDF (world units) -> occupancy with a one-voxel ramp */
      val = 0.5 - val / ls_at(ob, LS_VOXEL);
    }
    float s, v;
    vec3 cc;
    sample_color(ob, kind, val, x, s, cc, v);
#ifdef COLOR_GRID
    if (s > 0.0 && color_tf(ob) >= 0) { /* the colour grid's brick of this cell */
      cc = color_map(color_tf(ob), trilinear(brick_base(cid + cbrick0), clamp(x - cov_org[c], 0.0, BRICK_HI)));
    }
#endif
    if (g_lit[ob] != SHADING_EMISSION && s > 0.0) {
      cc = shade_sample(ob, cc, trilinear_grad(cov_base[c], clamp(x - cov_org[c], 0.0, BRICK_HI)), x, r, t);
    }
    if (s > 0.0) {
      sig += s;
      col += s * cc;
      if (!isnan(v)) {
        vs += s * v;
        vw += s;
      }
    }
  }
  if (best >= 0) {
    int ob = cov_obj[best], cid = cov_cell[best];
    vec3 x = g_ro[ob] + bt * g_rd[ob];
    vec3 g = trilinear_grad(cov_base[best], brick_xyz(cid, x));
    if (sig > 0.0 && bt > t - 0.5 * h) {
      composite(st, sig * (bt - (t - 0.5 * h)), col / sig, vw > 0.0 ? vs / vw : 0.0 / 0.0,
                t - 0.5 * h, bt);
    }
    surface_hit(st, ob, bt, g, x);
    return true;
  }
  if (sig > 0.0) {
    composite(st, sig * h, col / sig, vw > 0.0 ? vs / vw : 0.0 / 0.0, t - 0.5 * h, t + 0.5 * h);
    if (st.tr < st.tmin) {
      return true;
    }
  }
  return false;
}

/* One loop over the samples of all pieces (a nested piece / sample loop would keep the lanes
 * of a SIMD group waiting on each other twice). Pieces lie between the sorted interval
 * boundaries of all objects' walks (_cpu.merged_pieces). */
void trace_mode(Ray r, inout State st)
{
  Walk w[MAX_OBJ];
  float ta[MAX_OBJ], tb[MAX_OBJ];
  int cid[MAX_OBJ];
  bool alive[MAX_OBJ];
  float p = INF;
  for (int ob = 0; ob < n_obj; ob++) {
    sp_phi[ob] = 0.0;
    sp_t[ob] = 0.0 / 0.0;
    w[ob] = walk_start(ob, max(r.tn, g_rclip[ob].x), min(r.tf, g_rclip[ob].y));
    alive[ob] = walk_next(w[ob], ta[ob], tb[ob], cid[ob]);
    if (alive[ob]) {
      p = min(p, ta[ob]);
    }
  }
  int ncov = 0, n = 0, i = 0;
  float q = p, h = 0.0;
  while (true) {
    if (i >= n) { /* the next piece [p, q] */
      p = q;
      bool any = false;
      float first = INF;
      for (int ob = 0; ob < n_obj; ob++) {
        while (alive[ob] && tb[ob] <= p) {
          alive[ob] = walk_next(w[ob], ta[ob], tb[ob], cid[ob]);
        }
        if (alive[ob]) {
          any = true;
          first = min(first, ta[ob]);
        }
      }
      if (!any) {
        return;
      }
      p = max(p, first);
      q = INF;
      ncov = 0;
      for (int ob = 0; ob < n_obj; ob++) {
        if (!alive[ob]) {
          continue;
        }
        q = min(q, ta[ob] > p ? ta[ob] : tb[ob]);
        if (ta[ob] <= p) {
          cov_obj[ncov] = ob;
          cov_cell[ncov] = cid[ob];
          ncov++;
        }
      }
      piece_start(p, q, ncov, n, h);
      i = 0;
    }
    if (reference_sample(st, r, p + (float(i) + 0.5) * h, p, h, ncov)) {
      return;
    }
    i++;
  }
}
