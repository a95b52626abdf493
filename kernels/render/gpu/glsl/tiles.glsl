/* The screen-tile lists built on the GPU (gpu.tables_tiles; the float32 twin of
 * cpu.tiles.gauss_footprints, tile_counts and tile_fill), in three passes, one per STAGE_*:
 * FOOT (one invocation per Gaussian): pixel rectangle and entry bound, entries counted per
 *   tile with imageAtomicAdd; the host reads the counts back for the prefix sum (t_start);
 * FILL (per Gaussian): each entry's slot from a second atomic counter per tile, written with
 *   its pixel mask (gpu.tables_gauss.tile_tables' layout) and its tile;
 * SORT (per entry): its place in its tile by (entry bound, id), from its rank there.
 * Float32 rounding: the rectangle is widened by MARGIN_PX and the bound lowered a little more
 * than the CPU's, so every Gaussian the CPU lists in a tile is listed here too. */
#define MARGIN_PX 0.02  /* (the GPU's own: wider than cpu.tiles.MARGIN_PX) */
#define INF (1.0 / 0.0)

vec4 texel(sampler2D t, int e) { return texelFetch(t, ivec2(e % ROW_TEXELS, e / ROW_TEXELS), 0); }
ivec2 at(int e) { return ivec2(e % ROW_TEXELS, e / ROW_TEXELS); }
float scalar(sampler2D t, int e)
{
  vec4 v = texel(t, e >> 2);
  int c = e & 3;
  return c == 0 ? v.x : (c == 1 ? v.y : (c == 2 ? v.z : v.w));
}
/* float e (< 8) of a record held in the two texels a, b */
float in2(vec4 a, vec4 b, int e)
{
  return e < 4 ? a[e & 3] : b[e & 3];
}
int invocation() { return int(gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x); }

#ifdef STAGE_FOOT
ivec2 px_range(float lo, float hi, float off, float ext, int n)
{
  float fn = float(n);
  float a = (lo - off) / ext * fn + 0.5 * fn - 0.5 - MARGIN_PX;
  float b = (hi - off) / ext * fn + 0.5 * fn - 0.5 + MARGIN_PX;
  a = clamp(a, -1.0, fn + 1.0);
  b = clamp(b, -1.0, fn + 1.0);
  return ivec2(max(int(ceil(a)), 0), min(int(floor(b)), n - 1));
}

vec2 roots(float c, float cz, float sxx, float sxz, float szz)
{
  float a = cz * cz - szz, b = c * cz - sxz;
  float disc = b * b - a * (c * c - sxx);
  float r = disc > 0.0 ? sqrt(disc) : 0.0;
  float u0 = (-b - r) / a, u1 = (-b + r) / a;
  return vec2(min(u0, u1), max(u0, u1));
}

vec2 straddle_range(float c, float cz, float sxx, float sxz, float szz, float off, float ext)
{
  float lo = off - 0.5 * ext, hi = off + 0.5 * ext;
  float a = cz * cz - szz, b = c * cz - sxz, cc = c * c - sxx;
  float disc = b * b - a * cc;
  if (a >= 0.0 || disc <= 0.0) return vec2(lo, hi);
  float r = sqrt(disc);
  float u0 = min((-b - r) / a, (-b + r) / a), u1 = max((-b - r) / a, (-b + r) / a);
  bool left = u0 >= lo, right = u1 <= hi;
  if (left && right) return vec2(lo, hi);
  if (left) return vec2(lo, min(u0, hi));
  if (right) return vec2(max(u1, lo), hi);
  return vec2(hi + 1.0, lo - 1.0);
}

void main()
{
  int g = invocation();
  if (g >= n_g) return;
  ivec4 box = ivec4(1, 0, 1, 0);
  float lb = INF;
  vec4 ga = texel(tl_g, 2 * g), gb = texel(tl_g, 2 * g + 1);  /* TLG_SIZE == 8 */
  int W = int(scalar(tl_par, TLP_W)), H = int(scalar(tl_par, TLP_H));
  float ex = scalar(tl_par, TLP_EX), ey = scalar(tl_par, TLP_EY);
  float offx = scalar(tl_par, TLP_OX), offy = scalar(tl_par, TLP_OY), k = scalar(tl_par, TLP_K);
  bool ortho = scalar(tl_par, TLP_ORTHO) > 0.5;
  if (in2(ga, gb, TLG_W) != 0.0) {
    int o = TLP_SIZE + TLO_SIZE * int(in2(ga, gb, TLG_OBJ));  /* the object's TLO */
    vec4 B0 = texel(tl_par, (o + TLO_CMAT) >> 2), B1 = texel(tl_par, ((o + TLO_CMAT) >> 2) + 1);
    vec4 B2 = texel(tl_par, ((o + TLO_CMAT) >> 2) + 2);
    float onorm = scalar(tl_par, o + TLO_NORM);
    /* cmat rows (3 x 4, row-major): B0 = row 0 [0..3], B1 = row 1 [0..3], B2 = row 2 [0..3] */
    vec3 m = vec3(in2(ga, gb, TLG_MU), in2(ga, gb, TLG_MU + 1), in2(ga, gb, TLG_MU + 2));
    vec3 iv = vec3(in2(ga, gb, TLG_INV), in2(ga, gb, TLG_INV + 1), in2(ga, gb, TLG_INV + 2));
    float cx = dot(B0.xyz, m) + B0.w, cy = dot(B1.xyz, m) + B1.w, cz = dot(B2.xyz, m) + B2.w;
    vec3 s = k / iv;
    s = s * s;
    float sxx = dot(B0.xyz * B0.xyz, s), syy = dot(B1.xyz * B1.xyz, s), szz = dot(B2.xyz * B2.xyz, s);
    float sxz = dot(B0.xyz * B2.xyz, s), syz = dot(B1.xyz * B2.xyz, s);
    bool any_px = true;
    float lbg;
    ivec2 ri, rj;
    if (ortho) {
      float rz = sqrt(szz), rx = sqrt(sxx), ry = sqrt(syy);
      ri = px_range(cx - rx, cx + rx, offx, ex, W);
      rj = px_range(cy - ry, cy + ry, offy, ey, H);
      lbg = -cz - rz;
    } else if (cz * cz > szz) {
      any_px = cz <= 0.0;  /* else wholly behind the eye */
      vec2 u = roots(cx, cz, sxx, sxz, szz), v = roots(cy, cz, syy, syz, szz);
      ri = px_range(u.x, u.y, offx, ex, W);
      rj = px_range(v.x, v.y, offy, ey, H);
      float rmax = onorm * k / min(iv.x, min(iv.y, iv.z));
      lbg = length(vec3(cx, cy, cz)) - rmax;
    } else {
      vec2 u = straddle_range(cx, cz, sxx, sxz, szz, offx, ex);
      vec2 v = straddle_range(cy, cz, syy, syz, szz, offy, ey);
      ri = px_range(u.x, u.y, offx, ex, W);
      rj = px_range(v.x, v.y, offy, ey, H);
      lbg = -INF;
    }
    if (any_px) {
      box = ivec4(ri, rj);
      lb = lbg - 2e-6 * (abs(lbg) + 1.0);  /* float32: a few ulps below (the CPU: 1e-9) */
    }
  }
  imageStore(tl_box, at(g), vec4(box));
  imageStore(t_lb, at(g), vec4(lb, 0.0, 0.0, 0.0));
  if (box.x > box.y || box.z > box.w) return;
  for (int ty = box.z / TILE; ty <= box.w / TILE; ty++) {
    for (int tx = box.x / TILE; tx <= box.y / TILE; tx++) {
      imageAtomicAdd(cnt, ivec2(tx, ty), 1u);
    }
  }
}
#endif

#ifdef STAGE_FILL
void main()
{
  int g = invocation();
  if (g >= n_g) return;
  ivec4 box = ivec4(texel(tl_box, g));
  if (box.x > box.y || box.z > box.w) return;
  for (int ty = box.z / TILE; ty <= box.w / TILE; ty++) {
    for (int tx = box.x / TILE; tx <= box.y / TILE; tx++) {
      int q = int(scalar(t_start, ty * ntx + tx)) + int(imageAtomicAdd(cnt, ivec2(tx, ty), 1u));
      int i0 = max(box.x - tx * TILE, 0), i1 = min(box.y - tx * TILE, TILE - 1);
      int j0 = max(box.z - ty * TILE, 0), j1 = min(box.w - ty * TILE, TILE - 1);
      uint row = (1u << uint(i1 + 1)) - (1u << uint(i0));  /* bits i0..i1 */
      uint lo = 0u, hi = 0u;  /* mask bits 0..31 (rows 0-3), 32..63 (rows 4-7) */
      for (int y = j0; y <= j1; y++) {
        if (y < 4) lo |= row << uint(TILE * y); else hi |= row << uint(TILE * (y - 4));
      }
      /* the 64-bit mask (lo, hi words) in pieces of MASK_BITS (22, 22, 20), as TENT holds them */
      const uint hb = uint(2 * MASK_BITS - 32);  /* the second piece's bits in hi */
      uint p0 = lo & ((1u << uint(MASK_BITS)) - 1u);
      uint p1 = (lo >> uint(MASK_BITS)) | ((hi & ((1u << hb) - 1u)) << (32u - uint(MASK_BITS))), p2 = hi >> hb;
      imageStore(t_raw, at(q), vec4(float(g), float(p0), float(p1), float(p2)));  /* TENT_ID, TENT_MASK.. */
      imageStore(t_tile, at(q), vec4(float(ty * ntx + tx), 0.0, 0.0, 0.0));
    }
  }
}
#endif

#ifdef STAGE_SORT
/* one invocation per entry: its rank in its tile by (entry bound, id), counted over the tile's
 * unsorted entries (reads only: no image read after write, which llvmpipe ran out of order) */
void main()
{
  int q = invocation();
  if (q >= n_ent) return;
  vec4 e = texel(t_raw, q);
  int t = int(texel(t_tile, q).x);
  int a = int(scalar(t_start, t)), b = int(scalar(t_start, t + 1));
  float ke = texel(t_lb, int(e.x)).x;
  int rank = 0;
  for (int i = a; i < b; i++) {
    float gi = texel(t_raw, i).x;
    float ki = texel(t_lb, int(gi)).x;
    rank += (ki < ke || (ki == ke && gi < e.x)) ? 1 : 0;
  }
  imageStore(t_ent, at(a + rank), e);
}
#endif
