/* GaussVDB GPU device: what every mode shares. Create-info dialect: the resources (samplers
 * frame, objs, tf_lut, tf_par, lights and the mode's; images out_rgba, out_dv; push constants
 * row0, col0, nrows, ncols, n_obj, obj_texels, n_lights and the mode's; sh_tau) are declared by the glue
 * (gaussvdb_addon/gpu/compute.py), and with them every record's field offsets and the shared
 * constants (CAM_*, SET_*, OBJ_*, LS_*, PAR_*, LEAF, BG_DEPTH, KIND_*, ...: kernels/render/inputs/layout.py).
 * Tables: kernels/render/gpu/tables.py. Float32 throughout: the CPU device's float64 steps, in the
 * same order. */

#define INF (1.0 / 0.0)

/* -- table fetches ------------------------------------------------------------------------- */
vec4 texel(sampler2D t, int e)
{
  return texelFetch(t, ivec2(e % ROW_TEXELS, e / ROW_TEXELS), 0);
}
/* texel k of row i of a table whose rows take per texels (gpu_layout.fold_rows) */
vec4 row_texel(sampler2D t, int i, int per, int k)
{
  return texel(t, i * per + k);
}
/* element e of a scalar table (gpu_layout.fold_scalars) */
float scalar(sampler2D t, int e)
{
  vec4 v = texel(t, e >> 2);
  int c = e & 3;
  return c == 0 ? v.x : (c == 1 ? v.y : (c == 2 ? v.z : v.w));
}
int iscalar(sampler2D t, int e)
{
  return int(scalar(t, e));
}
float fr(int k)
{
  return scalar(frame, k);
}
/* the camera's field k (CAM_*), a setting (SET_*) */
float cam(int k)
{
  return fr(FR_CAM + k);
}
float setting(int k)
{
  return fr(FR_SET + k);
}
vec4 obj_texel(int ob, int k)
{
  return row_texel(objs, ob, obj_texels, k);
}
/* float e of object ob's row (OBJ_*); the three from e (e % 4 == 0); field k of its ls (LS_*) */
float obj_at(int ob, int e)
{
  return scalar(objs, ob * obj_texels * 4 + e);
}
vec3 obj_vec3(int ob, int e)
{
  return obj_texel(ob, e >> 2).xyz;
}
float ls_at(int ob, int k)
{
  return obj_at(ob, OBJ_LS + k);
}

/* -- the ray ------------------------------------------------------------------------------- */
/* world ray of every object in index space, and its clip interval (render_pixels) */
vec3 g_ro[MAX_OBJ];
vec3 g_rd[MAX_OBJ];
vec2 g_rclip[MAX_OBJ];
/* each object's kind (KIND_*), transfer function row and its parameters (PAR_*), read once per
 * pixel */
int g_kind[MAX_OBJ];
int g_tfi[MAX_OBJ];
vec4 g_par[MAX_OBJ];
int g_lit[MAX_OBJ]; /* SHADING_* */

struct Ray {
  vec3 o, d; /* world origin, unit direction */
  float tn, tf; /* the camera's clip range along this ray */
};

Ray camera_ray(int i, int j)
{
  float W = cam(CAM_W), Hh = cam(CAM_H);
  float ex = cam(CAM_EX), ey = cam(CAM_EY), offx = cam(CAM_OX), offy = cam(CAM_OY);
  float py = ((float(j) + 0.5) / Hh - 0.5) * ey + offy;
  float px = ((float(i) + 0.5) / W - 0.5) * ex + offx;
  /* the rotation's rows (CAM_ROT, row-major) and the position */
  vec3 r0 = vec3(cam(CAM_ROT), cam(CAM_ROT + 1), cam(CAM_ROT + 2));
  vec3 r1 = vec3(cam(CAM_ROT + 3), cam(CAM_ROT + 4), cam(CAM_ROT + 5));
  vec3 r2 = vec3(cam(CAM_ROT + 6), cam(CAM_ROT + 7), cam(CAM_ROT + 8));
  vec3 pos = vec3(cam(CAM_POS), cam(CAM_POS + 1), cam(CAM_POS + 2));
  float clip0 = cam(CAM_CLIP), clip1 = cam(CAM_CLIP + 1);
  Ray r;
  if (cam(CAM_KIND) < 0.5) {
    vec3 dc = vec3(r0.x * px + r0.y * py - r0.z, r1.x * px + r1.y * py - r1.z,
                   r2.x * px + r2.y * py - r2.z);
    float nrm = length(dc);
    r.d = dc / nrm;
    r.o = pos;
    r.tn = clip0 * nrm;
    r.tf = clip1 * nrm;
  }
  else {
    r.d = -vec3(r0.z, r1.z, r2.z);
    r.o = pos + px * vec3(r0.x, r1.x, r2.x) + py * vec3(r0.y, r1.y, r2.y);
    r.tn = clip0;
    r.tf = clip1;
  }
  return r;
}

/* the t interval of the world ray inside all of object ob's clip half-spaces */
vec2 clip_interval(int ob, vec3 o, vec3 d)
{
  float lo = -INF, hi = INF;
  int nclip = int(obj_at(ob, OBJ_NCLIP));
  for (int k = 0; k < nclip; k++) {
    vec4 hs = obj_texel(ob, OBJ_TEXELS + k);
    float num = dot(hs.xyz, o) + hs.w;
    float den = dot(hs.xyz, d);
    if (den > 0.0) {
      lo = max(lo, -num / den);
    }
    else if (den < 0.0) {
      hi = min(hi, -num / den);
    }
    else if (num < 0.0) {
      return vec2(INF, -INF);
    }
  }
  return vec2(lo, hi);
}

/* row r of object ob's world -> index matrix (OBJ_W2I, 3 x 4) */
vec4 w2i_row(int ob, int r)
{
  return obj_texel(ob, (OBJ_W2I >> 2) + r);
}

void object_rays(Ray r)
{
  for (int ob = 0; ob < n_obj; ob++) {
    vec4 m0 = w2i_row(ob, 0), m1 = w2i_row(ob, 1), m2 = w2i_row(ob, 2);
    g_ro[ob] = vec3(dot(m0.xyz, r.o) + m0.w, dot(m1.xyz, r.o) + m1.w, dot(m2.xyz, r.o) + m2.w);
    g_rd[ob] = vec3(dot(m0.xyz, r.d), dot(m1.xyz, r.d), dot(m2.xyz, r.d));
    g_rclip[ob] = clip_interval(ob, r.o, r.d);
    g_kind[ob] = int(obj_at(ob, OBJ_KIND));
    g_tfi[ob] = int(obj_at(ob, OBJ_TF));
    g_lit[ob] = int(obj_at(ob, OBJ_LIT));
    g_par[ob] = texel(tf_par, g_tfi[ob]);
  }
}

/* -- the leaf walk (cpu.walk.walk_object), one leaf cell after the other --------------------- */
#ifdef WALK
bool cell_skipped(int id)
{
  return scalar(cell_skip, id) != 0.0;
}

struct Walk {
  vec3 q, d; /* q-space origin (index + 0.5), direction */
  ivec3 c, s, lo, hi; /* cell, step, cell range [lo, hi) (in cells of leaf * scale) */
  vec3 m, e; /* t of the next boundary per axis, t per cell */
  float t, t1;
  float size;
  int ob, noff;
  ivec3 nmin, ndims;
  bool done;
};

vec2 slab(vec3 o, vec3 d, vec3 lo, vec3 hi, float t0, float t1)
{
  for (int k = 0; k < 3; k++) {
    if (d[k] == 0.0) {
      if (o[k] < lo[k] || o[k] > hi[k]) {
        return vec2(1.0, 0.0);
      }
    }
    else {
      float inv = 1.0 / d[k];
      float ta = (lo[k] - o[k]) * inv, tb = (hi[k] - o[k]) * inv;
      t0 = max(t0, min(ta, tb));
      t1 = min(t1, max(ta, tb));
    }
  }
  return vec2(t0, t1);
}

/* object ob's leaves (its node grid: OBJ_NODE_*) along its index ray over [tn, tf] */
Walk walk_start(int ob, float tn, float tf)
{
  Walk w;
  w.ob = ob;
  w.nmin = ivec3(obj_vec3(ob, OBJ_NODE_MIN));
  w.noff = int(obj_at(ob, OBJ_NODE_OFF));
  w.ndims = ivec3(obj_vec3(ob, OBJ_NODE_DIMS));
  w.size = float(LEAF) * obj_at(ob, OBJ_WALK_SCALE);
  w.q = g_ro[ob] + 0.5;
  w.d = g_rd[ob];
  w.done = w.ndims.x == 0;
  if (w.done) {
    return w;
  }
  float node = w.size * float(NODE_LEAVES);
  vec2 tt = slab(w.q, w.d, vec3(w.nmin) * node, vec3(w.nmin + w.ndims) * node, tn, tf);
  w.done = !(tt.x < tt.y);
  w.t = tt.x;
  w.t1 = tt.y;
  w.lo = w.nmin * NODE_LEAVES;
  w.hi = (w.nmin + w.ndims) * NODE_LEAVES;
  for (int k = 0; k < 3; k++) {
    int c = int(floor((w.q[k] + w.t * w.d[k]) / w.size));
    c = clamp(c, w.lo[k], w.hi[k] - 1);
    w.c[k] = c;
    if (w.d[k] > 0.0) {
      w.s[k] = 1;
      w.m[k] = (float(c + 1) * w.size - w.q[k]) / w.d[k];
      w.e[k] = w.size / w.d[k];
    }
    else if (w.d[k] < 0.0) {
      w.s[k] = -1;
      w.m[k] = (float(c) * w.size - w.q[k]) / w.d[k];
      w.e[k] = -w.size / w.d[k];
    }
    else {
      w.s[k] = 0;
      w.m[k] = INF;
      w.e[k] = INF;
    }
  }
  return w;
}

int floor_div16(int c)
{
  return c >= 0 ? c / NODE_LEAVES : -((NODE_LEAVES - 1 - c) / NODE_LEAVES);
}

/* the cell id at leaf-cell coordinates c, or -1 */
int cell_at(Walk w, ivec3 c)
{
  ivec3 n = ivec3(floor_div16(c.x), floor_div16(c.y), floor_div16(c.z));
  ivec3 r = n - w.nmin;
  int nid = iscalar(node_table, w.noff + (r.x * w.ndims.y + r.y) * w.ndims.z + r.z);
  if (nid < 0) {
    return -1;
  }
  ivec3 l = c - n * NODE_LEAVES;
  return iscalar(node_cells, nid * NODE_LEAVES * NODE_LEAVES * NODE_LEAVES
                 + (l.x * NODE_LEAVES + l.y) * NODE_LEAVES + l.z);
}

/* the next non-empty, not skipped cell's interval [ta, tb] and id (skip: cell_skipped(id)) */
bool walk_next(inout Walk w, out float ta, out float tb, out int cid)
{
  while (!w.done) {
    float tn = min(min(w.m.x, w.m.y), min(w.m.z, w.t1));
    int id = -1;
    if (tn > w.t) {
      id = cell_at(w, w.c);
      if (id >= 0 && cell_skipped(id)) {
        id = -1;
      }
    }
    float t = w.t;
    if (tn >= w.t1) {
      w.done = true;
    }
    else {
      int k = (w.m.x <= w.m.y && w.m.x <= w.m.z) ? 0 : (w.m.y <= w.m.z ? 1 : 2);
      w.c[k] += w.s[k];
      w.m[k] += w.e[k];
      if (w.c[k] < w.lo[k] || w.c[k] >= w.hi[k]) {
        w.done = true;
      }
      w.t = max(w.t, tn);
    }
    if (id >= 0) {
      ta = t;
      tb = tn;
      cid = id;
      return true;
    }
  }
  return false;
}
#endif

/* -- transfer functions (cpu.vecmath: tf_x, lut_pos, sample_color) ---------------------------- */
vec4 lut_at(int tfi, float x)
{
  float f = x * float(LUT_SIZE - 1);
  int i = clamp(int(f), 0, LUT_SIZE - 2);
  float w = f - float(i);
  return texelFetch(tf_lut, ivec2(i, tfi), 0) * (1.0 - w) + texelFetch(tf_lut, ivec2(i + 1, tfi), 0) * w;
}

float log10f(float v)
{
  return log2(v) * 0.30102999566398120;
}

/* normalised TF coordinate in [0, 1]; NaN stays NaN */
float tf_x(float v, vec4 par)
{
  float x;
  if (isnan(v)) {
    return v;
  }
  if (par[PAR_LOG] > 0.5) {
    float lo = log10f(par[PAR_VMIN]), hi = log10f(par[PAR_VMAX]);
    float lv = v > 0.0 ? log10f(v) : -INF;
    x = hi > lo ? (lv - lo) / (hi - lo) : (lv >= hi ? 1.0 : 0.0);
  }
  else {
    float vmin = par[PAR_VMIN], vmax = par[PAR_VMAX];
    x = vmax > vmin ? (v - vmin) / (vmax - vmin) : (v >= vmax ? 1.0 : 0.0);
  }
  return clamp(x, 0.0, 1.0);
}

/* a level set's albedo at index point p: constant, or the colormap over a world coordinate */
vec3 ls_color(int ob, int tfi, vec3 p)
{
  if (ls_at(ob, LS_CONST) > 0.5) {
    return vec3(ls_at(ob, LS_COLOR), ls_at(ob, LS_COLOR + 1), ls_at(ob, LS_COLOR + 2));
  }
  float c = ls_at(ob, LS_PLANE) * p.x + ls_at(ob, LS_PLANE + 1) * p.y + ls_at(ob, LS_PLANE + 2) * p.z
            + ls_at(ob, LS_PLANE + 3);
  float lo = ls_at(ob, LS_RANGE), hi = ls_at(ob, LS_RANGE + 1);
  float u = hi > lo ? (c - lo) / (hi - lo) : 0.5;
  return lut_at(tfi, clamp(u, 0.0, 1.0)).rgb;
}

/* sigma_t, linear colour and value (NaN: none) of object ob for field value s at index point p */
void sample_color(int ob, int kind, float s, vec3 p, out float sig, out vec3 col, out float val)
{
  int tfi = g_tfi[ob];
  vec4 par = g_par[ob];
  sig = 0.0;
  col = vec3(0.0);
  val = 0.0 / 0.0;
  if (kind == KIND_SHELL) {
    float occ = min(s, 1.0);
    if (!(occ > 0.0)) {
      return;
    }
    sig = par[PAR_DENSITY] * occ;
    col = ls_color(ob, tfi, p);
    return;
  }
  float x = tf_x(s, par);
  if (isnan(x)) {
    return;
  }
  vec4 c = lut_at(tfi, x);
  sig = par[PAR_DENSITY] * c.a;
  col = c.rgb;
  val = s;
}

/* -- the ray's state and compositing (cpu.vecmath.composite) ---------------------------------- */
struct State {
  float tr; vec3 rad; float depth, vsum, vwt, tmin;
  bool hit; float hit_t; vec3 hit_g; int hit_ob; vec3 hit_c;
};

State state_start()
{
  State st;
  st.tr = 1.0;
  st.rad = vec3(0.0);
  st.depth = BG_DEPTH;
  st.vsum = 0.0;
  st.vwt = 0.0;
  st.tmin = setting(SET_TMIN);
  st.hit = false;
  st.hit_t = 0.0;
  st.hit_g = vec3(0.0);
  st.hit_ob = 0;
  st.hit_c = vec3(0.0);
  return st;
}

/* e^-tau - 1 without float32's cancellation for small tau */
float expm1_neg(float tau)
{
  if (tau < 1e-2) {
    return -tau * (1.0 - tau * 0.5 * (1.0 - tau / 3.0 * (1.0 - 0.25 * tau)));
  }
  return exp(-tau) - 1.0;
}

void composite(inout State st, float tau, vec3 c, float v, float ta, float tb)
{
  if (!(tau > 0.0)) {
    return;
  }
  float T = st.tr;
  float em = expm1_neg(tau);
  float w = -T * em;
  st.rad += w * c;
  if (!isnan(v)) {
    st.vsum += w * v;
    st.vwt += w;
  }
  float Tn = T * (1.0 + em);
  if (st.depth == BG_DEPTH && Tn <= 0.5) {
    float f = T > 0.5 ? log(T / 0.5) / tau : 0.0;
    st.depth = ta + f * (tb - ta);
  }
  st.tr = Tn;
}

/* the ray ends on object ob's surface at t (index point p, index-space gradient g) */
void surface_hit(inout State st, int ob, float t, vec3 g, vec3 p)
{
  st.hit = true;
  st.hit_t = t;
  st.hit_g = g;
  st.hit_ob = ob;
  st.hit_c = ls_color(ob, g_tfi[ob], p);
  if (st.depth == BG_DEPTH) {
    st.depth = t;
  }
}

/* light k seen from world point p on a ray of direction d: unit direction towards it and its
 * irradiance (cpu.surface.light_at: points fall off as 1 / r^2, the headlight shines along d) */
bool light_at(int k, vec3 p, vec3 d, out vec3 l, out vec3 e)
{
  vec4 a = row_texel(lights, k, 2, 0), b = row_texel(lights, k, 2, 1); /* LIGHT_KIND, _VEC; _RGB */
  l = -d;
  e = b.xyz;
  if (a.x == float(LIGHT_POINT)) {
    vec3 dl = a.yzw - p;
    float d2 = dot(dl, dl);
    if (!(d2 > 0.0)) {
      return false;
    }
    l = dl / sqrt(d2);
    e /= d2;
  }
  else if (a.x == float(LIGHT_SUN)) {
    l = -a.yzw;
  }
  return true;
}

/* optical depth towards light li at index point x from object ob's shadow grid, trilinear,
 * clamped (cpu.lit.shadow_tau) */
float shadow_tau(int ob, int li, vec3 x)
{
  int s = OBJ_SH_GRID;
  ivec3 nd = ivec3(obj_vec3(ob, s + SHG_DIMS));
  int off = int(obj_at(ob, s + SHG_OFFSET));
  vec3 u = clamp((x - obj_vec3(ob, s + SHG_ORIGIN)) / obj_at(ob, s + SHG_SPACING), vec3(0.0), vec3(nd) - 1.0);
  ivec3 i0 = min(ivec3(u), nd - 2);
  vec3 a = u - vec3(i0);
  float v = 0.0;
  for (int di = 0; di < 2; di++) {
    for (int dj = 0; dj < 2; dj++) {
      for (int dk = 0; dk < 2; dk++) {
        float w = (di == 1 ? a.x : 1.0 - a.x) * (dj == 1 ? a.y : 1.0 - a.y) * (dk == 1 ? a.z : 1.0 - a.z);
        int e = off + (((i0.x + di) * nd.y + i0.y + dj) * nd.z + i0.z + dk) * n_lights + li;
        v += w * scalar(sh_tau, e);
      }
    }
  }
  return v;
}

/* Blinn-Phong on a lit volume sample of object ob (cpu.lit.shade_sample): g the field's
 * index-space gradient at index point x, t the sample's distance along the world ray; replaces
 * the emission colour c unless the gradient is below the threshold */
vec3 shade_sample(int ob, vec3 c, vec3 g, vec3 x, Ray r, float t)
{
  vec4 par = g_par[ob];
  float rng = par[PAR_VMAX] - par[PAR_VMIN];
  if (!(rng > 0.0)) {
    rng = 1.0;
  }
  if (!(length(g) > setting(SET_LIT_THRESHOLD) * rng)) {
    return c;
  }
  vec4 m0 = w2i_row(ob, 0), m1 = w2i_row(ob, 1), m2 = w2i_row(ob, 2);
  vec3 n = -(g.x * m0.xyz + g.y * m1.xyz + g.z * m2.xyz);
  float nn = length(n);
  if (!(nn > 0.0)) {
    return c;
  }
  n /= nn;
  vec3 p = r.o + t * r.d;
  float ka = setting(SET_SHADING), kd = setting(SET_SHADING + 1);
  float ks = setting(SET_SHADING + 2), sh = setting(SET_SHADING + 3);
  vec3 col = ka * c;
  for (int k = 0; k < n_lights; k++) {
    vec3 l, e;
    if (!light_at(k, p, r.d, l, e)) {
      continue;
    }
    float ndl = dot(n, l);
    if (ndl <= 0.0) {
      continue;
    }
    if (g_lit[ob] == SHADING_LIT_SHADOWS) {
      e *= exp(-shadow_tau(ob, k, x));
    }
    vec3 hv = l - r.d;
    float hn = length(hv);
    float spec = 0.0;
    if (hn > 0.0 && ks > 0.0) {
      spec = ks * pow(max(dot(n, hv), 0.0) / hn, sh);
    }
    col += e * (kd * ndl * c + spec);
  }
  return col;
}

/* Blinn-Phong at the hit (cpu.surface.shade_hit) */
void shade_hit(inout State st, Ray r)
{
  vec4 m0 = w2i_row(st.hit_ob, 0), m1 = w2i_row(st.hit_ob, 1), m2 = w2i_row(st.hit_ob, 2);
  vec3 g = st.hit_g;
  vec3 n = g.x * m0.xyz + g.y * m1.xyz + g.z * m2.xyz;
  float nn = length(n);
  n = nn > 0.0 ? n / nn : -r.d;
  if (dot(n, r.d) > 0.0) {
    n = -n;
  }
  vec3 p = r.o + st.hit_t * r.d;
  float ka = setting(SET_SHADING), kd = setting(SET_SHADING + 1);
  float ks = setting(SET_SHADING + 2), sh = setting(SET_SHADING + 3);
  vec3 c = ka * st.hit_c;
  for (int k = 0; k < n_lights; k++) {
    vec3 l, e;
    if (!light_at(k, p, r.d, l, e)) {
      continue;
    }
    float ndl = dot(n, l);
    if (ndl <= 0.0) {
      continue;
    }
    vec3 hv = l - r.d;
    float hn = length(hv);
    float spec = 0.0;
    if (hn > 0.0 && ks > 0.0) {
      spec = ks * pow(max(dot(n, hv), 0.0) / hn, sh);
    }
    c += e * (kd * ndl * st.hit_c + spec);
  }
  st.rad += st.tr * c;
  st.tr = 0.0;
}

/* Whether the driver cut this invocation's loops short. llvmpipe (Mesa's gallivm) ends every loop
 * after one pass once an invocation has made 65535 loop passes in all (LP_MAX_TGSI_LOOP_ITERATIONS),
 * silently; a loop that a branch skips still makes one pass there (its SIMD code runs it masked).
 * A loop of two passes, run last, then makes one. */
bool loops_cut()
{
  int n = 0;
  for (int i = 0; i < 2 + min(nrows, 0); i++) {  /* (nrows >= 1: two passes the compiler cannot unroll) */
    n++;
  }
  return n < 2;
}

/* the pixel's passes: rgba premultiplied over the background, depth, value (render_pixels) */
void write_output(ivec2 p, Ray r, State st)
{
  if (st.hit) {
    shade_hit(st, r);
  }
  vec4 bg = vec4(setting(SET_BG), setting(SET_BG + 1), setting(SET_BG + 2), setting(SET_BG + 3));
  float T = st.tr;
  imageStore(out_rgba, p, vec4(st.rad + T * bg.rgb * bg.a, (1.0 - T) + T * bg.a));
  imageStore(out_dv, p, vec4(st.depth, st.vwt > 0.0 ? st.vsum / st.vwt : 0.0, 0.0, 0.0));
}
