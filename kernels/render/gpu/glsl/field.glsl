/* Field mode (needs gauss.glsl before it; cpu.gauss.trace_tiles + sweep_field): the ray tests
 * its screen tile's Gaussians in list order and samples the summed field at the midpoints
 * t_i = (i + 1/2) h (h: the finest object step along the ray) once every chord entering before
 * t_i is known. Each active chord's value is evaluated at the sample (the CPU carries it by two
 * multiplications; the same value). Surfaces (KIND_SURFACE): the first crossing between samples
 * (field_crossing: with signed distances, the zero of their normalised mixture; else the 0.5
 * occupancy); the normal from the Gaussians around the hit
 * (mixture_normal). Entries wait in PCAP slots, active chords in PCAP more; a ray that needs
 * more gets OVERFLOW_DEPTH and the device draws its tile on the CPU. With LIT (lit volumes in the
 * frame), each lit sample is shaded on the mixture's analytic gradient (lit_enter, lit_sample). */

float f_e[PCAP], f_ts[PCAP], f_hq[PCAP], f_ha[PCAP];  /* waiting entries, by slot */
float a_e[PCAP], a_ts[PCAP], a_hq[PCAP], a_ha[PCAP], a_w[PCAP], a_c[PCAP];  /* active chords */
int a_ob[PCAP];
int nact, isamp;
float hstep, f_cend;
float sprev_v[MAX_OBJ], sprev_w[MAX_OBJ], sprev_t[MAX_OBJ], sprev_n[MAX_OBJ];
int sprev_i[MAX_OBJ];
bool f_over;

#ifdef LIT
/* lit volumes (cpu.gauss.sweep_field): active chord k's part of its object's mixture gradient at
 * t is -V (a_ga[k] + t a_gb[k]) (V its value there), summed per object and sample in f_grad */
vec3 a_ga[PCAP], a_gb[PCAP];
vec3 f_grad[MAX_OBJ];

void lit_enter(int k, Gauss G)
{
  vec3 i2 = G.iv * G.iv;
  a_ga[k] = i2 * (g_ro[a_ob[k]] - G.mu);
  a_gb[k] = i2 * g_rd[a_ob[k]];
}

void lit_move(int k, int j)
{
  a_ga[k] = a_ga[j];
  a_gb[k] = a_gb[j];
}

/* sample colour c of object ob at ti, Blinn-Phong on f_grad where the object is lit */
vec3 lit_sample(int ob, vec3 c, float ti)
{
  return g_lit[ob] == SHADING_EMISSION ? c : shade_sample(ob, c, f_grad[ob], g_ro[ob] + ti * g_rd[ob], lit_ray, ti);
}
#endif

/* object ob's surface at th inside the sample at ti: the sample's volumes up to th, then the hit */
void mixture_hit(inout State st, int ob, float th, float ti, float sig, vec3 col, float vs, float vw)
{
  float t0 = ti - 0.5 * hstep;
  if (sig > 0.0 && th > t0) {
    composite(st, sig * (th - t0), col / sig, vw > 0.0 ? vs / vw : 0.0 / 0.0, t0, th);
  }
  surface_hit(st, ob, th, vec3(0.0), g_ro[ob] + th * g_rd[ob]);
}

/* a signed-distance surface's single-layer level (gpu_layout.object_rows), 0 for none */
float obj_level(int ob) { return obj_at(ob, OBJ_LEVEL); }

/* object ob's surface between samples isamp - 1 and isamp at ti, or INF (cpu.surface.field_crossing:
 * level > 0, where S = nv / sv falls through 0 while sv >= SDF_OCCUPANCY, or the occupancy-weighted
 * centre of a passage through the shell that ends without it, its mean S below level; else where
 * sv rises through 0.5). sprev_i: the last sample, -1e9 for one outside the shell; the passage's
 * sums of sv (sprev_w), sv t (sprev_t) and nv (sprev_n). */
float field_crossing(int ob, float ti, float sv, float nv, float level)
{
  bool adjacent = sprev_i[ob] == isamp - 1;
  float prev = sprev_v[ob];
  if (!(level > 0.0)) {
    prev = adjacent ? prev : 0.0; /* none active: 0 */
    sprev_v[ob] = sv;
    sprev_i[ob] = isamp;
    return sv >= 0.5 && prev < 0.5 ? ti - hstep + (0.5 - prev) / (sv - prev) * hstep : INF;
  }
  if (sv < SDF_OCCUPANCY) {
    sprev_i[ob] = -1000000000;
    return adjacent && sprev_n[ob] < level * sprev_w[ob] ? sprev_t[ob] / sprev_w[ob] : INF;
  }
  float f = nv / sv;
  sprev_v[ob] = f;
  sprev_i[ob] = isamp;
  if (f <= 0.0) {
    return adjacent && prev > 0.0 ? ti - hstep + prev / (prev - f) * hstep : ti;
  }
  if (!adjacent) { /* a passage begins */
    sprev_w[ob] = 0.0;
    sprev_t[ob] = 0.0;
    sprev_n[ob] = 0.0;
  }
  sprev_w[ob] += sv;
  sprev_t[ob] += sv * ti;
  sprev_n[ob] += nv;
  return INF;
}

/* The samples before horizon (see the file's comment). True once the ray ends (opaque, a
 * surface, or f_over). */
bool sweep_field(inout State st, float horizon)
{
  for (int it = 0; it < 100000000; it++) {
    float ti = (float(isamp) + 0.5) * hstep;
    if (!(ti < horizon)) {
      break;
    }
    while (q0 < nq && q_t[q0] <= ti) {
      int h = q_h[q0], g = q_g[q0];
      q0++;
      if (nact == PCAP) {
        f_over = true;
        return true;
      }
      a_e[nact] = f_e[h];
      a_ts[nact] = f_ts[h];
      a_hq[nact] = f_hq[h];
      a_ha[nact] = f_ha[h];
      Gauss G = gauss_at(g);
      a_w[nact] = G.w;
      a_c[nact] = G.val; /* the signed-distance weight (gpu.tables_gauss.gauss_tables) */
      a_ob[nact] = n_obj == 1 ? 0 : G.ob;
#ifdef LIT
      lit_enter(nact, G);
#endif
      nact++;
      f_cend = max(f_cend, f_e[h]);
      slot_free(h);
    }
    if (nact > 0 && ti >= f_cend) {
      nact = 0; /* every active chord has ended */
    }
    if (nact == 0) {
      if (q0 == nq || !(q_t[q0] < horizon)) { /* nothing known ahead: resume at the horizon */
        if (horizon < INF) {
          isamp = max(isamp, int(ceil(horizon / hstep - 0.5)));
        }
        break;
      }
      isamp = max(isamp + 1, int(ceil(q_t[q0] / hstep - 0.5)));
      continue;
    }
    float sv[MAX_OBJ], nv[MAX_OBJ];
    bool sact[MAX_OBJ];
    for (int ob = 0; ob < n_obj; ob++) {
      sv[ob] = 0.0;
      nv[ob] = 0.0;
      sact[ob] = false;
#ifdef LIT
      f_grad[ob] = vec3(0.0);
#endif
    }
    int k = 0;
    while (k < nact) {
      if (a_e[k] <= ti) { /* ended before this sample: drop it */
        nact--;
        a_e[k] = a_e[nact];
        a_ts[k] = a_ts[nact];
        a_hq[k] = a_hq[nact];
        a_ha[k] = a_ha[nact];
        a_w[k] = a_w[nact];
        a_c[k] = a_c[nact];
        a_ob[k] = a_ob[nact];
#ifdef LIT
        lit_move(k, nact);
#endif
        continue;
      }
      float d = ti - a_ts[k];
      float e = exp(-(a_hq[k] + a_ha[k] * d * d));
      sv[a_ob[k]] += a_w[k] * e;
#ifdef LIT
      f_grad[a_ob[k]] -= a_w[k] * e * (a_ga[k] + ti * a_gb[k]);
#endif
      nv[a_ob[k]] += a_c[k] * e;
      sact[a_ob[k]] = true;
      k++;
    }
    if (n_obj == 1) {
      sact[0] = true;
    }
    float sig = 0.0, vs = 0.0, vw = 0.0, bt = INF;
    vec3 col = vec3(0.0);
    int best = -1;
    for (int ob = 0; ob < n_obj; ob++) {
      int kind = g_kind[ob];
      if (!sact[ob] && kind != KIND_SURFACE) { /* surfaces at every sample: a passage may end here */
        continue;
      }
      if (kind == KIND_SURFACE) {
        float th = field_crossing(ob, ti, sv[ob], nv[ob], obj_level(ob));
        if (th < bt) {
          bt = th;
          best = ob;
        }
        continue;
      }
      float sg, val;
      vec3 c;
      sample_color(ob, kind, sv[ob], g_ro[ob] + ti * g_rd[ob], sg, c, val);
#ifdef COLOR_GRID
      recolor(ob, nv[ob] + color_background(ob), sg, c); /* nv: the colour grid's mixture */
#endif
#ifdef LIT
      if (sg > 0.0) {
        c = lit_sample(ob, c, ti);
      }
#endif
      if (sg > 0.0) {
        sig += sg;
        col += sg * c;
        if (!isnan(val)) {
          vs += sg * val;
          vw += sg;
        }
      }
    }
    if (best >= 0) {
      mixture_hit(st, best, bt, ti, sig, col, vs, vw);
      return true;
    }
    isamp++;
    if (sig > 0.0) {
      composite(st, sig * hstep, col / sig, vw > 0.0 ? vs / vw : 0.0 / 0.0, ti - 0.5 * hstep,
                ti + 0.5 * hstep);
      if (st.tr < st.tmin) {
        return true;
      }
    }
  }
  return false;
}

/* the outward normal from the Gaussians centred in the leaf cells within NORMAL_REACH of the hit
 * (cpu.surface.mixture_normal): with signed distances, the gradient of their weighted
 * least-squares linear fit (fit_gradient); else -gradient of the mixture blurred by NORMAL_BLUR */
void mixture_normal(inout State st)
{
  bool sdf = obj_level(st.hit_ob) > 0.0;
  float s0 = 0.0, d0 = 0.0;
  vec3 s1 = vec3(0.0), d1 = vec3(0.0);
  mat3 s2 = mat3(0.0);
  int ob = st.hit_ob;
  vec3 x = g_ro[ob] + st.hit_t * g_rd[ob];
  ivec3 lo = ivec3(floor((x + 0.5 - NORMAL_REACH) / float(LEAF)));
  ivec3 hi = ivec3(floor((x + 0.5 + NORMAL_REACH) / float(LEAF)));
  Walk w;
  w.nmin = ivec3(obj_vec3(ob, OBJ_NODE_MIN));
  w.noff = int(obj_at(ob, OBJ_NODE_OFF));
  w.ndims = ivec3(obj_vec3(ob, OBJ_NODE_DIMS));
  vec3 grad = vec3(0.0);
  for (int cx = lo.x; cx <= hi.x; cx++) {
    for (int cy = lo.y; cy <= hi.y; cy++) {
      for (int cz = lo.z; cz <= hi.z; cz++) {
        ivec3 c = ivec3(cx, cy, cz);
        ivec3 n = ivec3(floor_div16(cx), floor_div16(cy), floor_div16(cz));
        if (any(lessThan(n, w.nmin)) || any(greaterThanEqual(n, w.nmin + w.ndims))) {
          continue;
        }
        int cid = cell_at(w, c);
        if (cid < 0) {
          continue;
        }
        int j1 = iscalar(c_start, cid + 1);
        for (int j = iscalar(c_start, cid); j < j1; j++) {
          int g = iscalar(c_items, j);
          Gauss G = gauss_at(g);
          if (ivec3(floor((G.mu + 0.5) / float(LEAF))) != c || G.w == 0.0) {
            continue; /* counted in the cell of its centre */
          }
          vec3 iv = G.iv;
          if (sdf) { /* the fit's sums, about the hit */
            vec3 u = G.mu - x;
            float qf = dot(u * iv, u * iv);
            if (qf > 16.0) {
              continue;
            }
            float e = exp(-0.5 * qf), ew = G.w * e;
            s0 += ew;
            s1 += ew * u;
            s2 += ew * outerProduct(u, u);
            d0 += G.val * e;
            d1 += G.val * e * u;
            continue;
          }
          vec3 ib = 1.0 / sqrt(1.0 / (iv * iv) + NORMAL_BLUR);
          vec3 u = (x - G.mu) * ib;
          float q = dot(u, u);
          if (q > 16.0) {
            continue;
          }
          float e = G.w * ib.x * ib.y * ib.z / (iv.x * iv.y * iv.z) * exp(-0.5 * q);
          grad += e * u * ib;
        }
      }
    }
  }
  if (sdf && s0 > 0.0) { /* cpu.surface.fit_gradient */
    vec3 m = s1 / s0;
    mat3 c = s2 / s0 - outerProduct(m, m);
    vec3 b = d1 / s0 - m * (d0 / s0);
    float tr = c[0][0] + c[1][1] + c[2][2], det = determinant(c);
    vec3 a0 = cross(c[1], c[2]), a1 = cross(c[2], c[0]), a2 = cross(c[0], c[1]); /* adj(c) */
    grad = det > 1e-9 * tr * tr * tr ? mat3(a0, a1, a2) * b / det : vec3(0.0);
    float slope = obj_level(st.hit_ob) / SURFACE_LEVEL; /* one layer: the layer's normal */
    if (dot(grad, grad) < 0.25 * slope * slope) {
      float n0 = dot(a0, a0), n1 = dot(a1, a1), n2 = dot(a2, a2);
      grad = n0 >= n1 && n0 >= n2 ? a0 : (n1 >= n2 ? a1 : a2);
    }
  }
  st.hit_g = grad;
}

bool trace_tiles(float tn, float tf, inout State st)
{
  float k2 = setting(SET_K) * setting(SET_K);
  ivec3 tb = pixel_tile();
  int t1 = tile_first(tb.x + 1);
  slots_start();
  nact = 0;
  isamp = 0;
  f_cend = -INF;
  f_over = false;
  hstep = INF;
  for (int ob = 0; ob < n_obj; ob++) {
    hstep = min(hstep, obj_at(ob, OBJ_STEP) / length(g_rd[ob]));
    sprev_i[ob] = -1000000000;
    sprev_v[ob] = 0.0;
  }
  int nh = 0, swept = 0, q = tile_first(tb.x);
  Gauss G;
  vec4 c;
  float aa, qq, ra;
  for (int g = next_hit(q, t1, tb.y, k2, tn, tf, G, c, aa, qq, ra); g >= 0;
       g = next_hit(q, t1, tb.y, k2, tn, tf, G, c, aa, qq, ra)) {
    float lbg = entry_bound(G, g);
    if (nh >= swept + BATCH && q0 < nq && q_t[q0] < lbg) {
      swept = nh;
      if (sweep_field(st, lbg)) {
        return !f_over;
      }
    }
    if (nfree == 0) {
      if (sweep_field(st, lbg)) {
        return !f_over;
      }
      if (nfree == 0) {
        return false;
      }
    }
    nfree--;
    int h = fre[nfree];
    f_e[h] = c.y;
    f_ts[h] = c.z;
    f_hq[h] = 0.5 * qq;
    f_ha[h] = 0.5 * aa;
    queue_insert(c.x, g, h);
    nh++;
  }
  sweep_field(st, INF);
  return !f_over;
}

void trace_mode(Ray r, inout State st)
{
#ifdef LIT
  lit_ray = r;
#endif
  if (!trace_tiles(r.tn, r.tf, st)) {
    st.depth = OVERFLOW_DEPTH; /* the device draws this pixel's tile on the CPU */
    return;
  }
  if (st.hit) {
    mixture_normal(st);
  }
}
