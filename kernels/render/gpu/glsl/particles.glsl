/* Particles mode (needs gauss.glsl before it; cpu.gauss.trace_tiles + sweep_particles, cpu.chords.close_interval): one ray
 * tests its screen tile's Gaussians in list order (by entry bound) and sweeps their chords in
 * (t, id) order; overlapping chords form clusters whose intervals get closed-form optical depth.
 * The hits live in PCAP fixed slots: a slot is freed when its chord's cluster interval closes
 * past its exit. When every slot is taken the ray sweeps up to the next candidate's entry bound
 * (all entries before it are known, and the sweep's result does not depend on when it runs);
 * if that frees none, the pixel's depth is OVERFLOW_DEPTH and the device draws its tile on the
 * CPU. With LIT (lit volumes in the frame), a lit chord's colour is shaded as it is found
 * (lit_chord). */
float h_s[PCAP], h_e[PCAP], h_ts[PCAP], h_sa[PCAP], h_c[PCAP], h_pk[PCAP], h_fa[PCAP], h_fb[PCAP];
vec3 h_col[PCAP];
float h_val[PCAP], h_vw[PCAP];
int mem[PCAP];
int nm;
float s_a, s_last, s_rho, s_cend;
vec3 cb_lo, cb_hi;  /* the open members' colour bounds */

#ifdef LIT
/* a lit volume's chord colour (cpu.lit.lit_member): col shaded once at its closest approach ts
 * (qq: the whitened squared distance there) on the mixture's gradient, the Gaussian's own
 * (analytic) plus its neighbours' at its centre (g_grad: xyz, and its own field weight in w) */
vec3 lit_chord(Gauss G, int g, float ts, float qq, vec3 col)
{
  int ob = n_obj == 1 ? 0 : G.ob;
  if (g_lit[ob] == SHADING_EMISSION) {
    return col;
  }
  vec4 n = texel(g_grad, g);
  vec3 x = g_ro[ob] + ts * g_rd[ob];
  vec3 grad = n.xyz - n.w * exp(-0.5 * qq) * (x - G.mu) * G.iv * G.iv;
  return shade_sample(ob, col, grad, x, lit_ray, ts);
}
#endif

void reset_bounds() { cb_lo = vec3(INF); cb_hi = vec3(-INF); }
void widen(int h) { cb_lo = min(cb_lo, h_col[h]); cb_hi = max(cb_hi, h_col[h]); }
float spread_of() { vec3 d = cb_hi - cb_lo; return max(d.x, max(d.y, d.z)); }

float erf_at(int h, float t) { return erf_g(h_sa[h] * (clamp(t, h_s[h], h_e[h]) - h_ts[h])); }

float chord_tau(int h, float a, float b) {
  a = max(a, h_s[h]); b = min(b, h_e[h]);
  if (!(b > a)) return 0.0;
  float sa = h_sa[h], ts = h_ts[h];
  return h_c[h] * erf_span(sa * (a - ts), sa * (b - ts), sa * (b - a));
}

void median_depth(inout State st, int h, float a, float b, float tsum) {
  float T = st.tr;
  if (st.depth != BG_DEPTH || T * exp(-tsum) > 0.5) return;
  float target = T > 0.5 ? log(T / 0.5) : 0.0;
  float lo = a, hi = b;
  for (int it = 0; it < 40; it++) {
    float mid = 0.5 * (lo + hi);
    if (chord_tau(h, a, mid) < target) lo = mid; else hi = mid;
  }
  st.depth = 0.5 * (lo + hi);
}

void composite_mix(inout State st, float tsum, vec3 c, float vs, float vw, float a, float b) {
  composite(st, tsum, c / tsum, vw > 0.0 ? vs / vw : 0.0 / 0.0, a, b);
}

/* Composite the members' optical depth over [a, b]; the members still open at b stay in mem[:n]
 * (n returned) with their peak-density sum in rho and colour bounds; the others' slots are freed. */
int close_interval(inout State st, float a, float b, float spread, float tau_max, out float rho) {
  float tsum = 0.0, vs = 0.0, vw = 0.0;
  vec3 c = vec3(0.0);
  int n = 0;
  rho = 0.0;
  reset_bounds();
  for (int k = 0; k < nm; k++) {
    int h = mem[k];
    float fb = erf_at(h, b);
    float tk = h_c[h] * (fb - h_fa[h]);
    h_fb[h] = h_fa[h];
    h_fa[h] = fb;
    tsum += tk; c += tk * h_col[h]; vs += tk * h_val[h]; vw += tk * h_vw[h];
    if (h_e[h] > b) { n++; rho += h_pk[h]; widen(h); }
  }
  if (tsum > 0.0) {
    int nsub = 1;
    if (nm > 1 && tau_max > 0.0 && tsum * spread > tau_max) nsub = min(int(ceil(tsum * spread / tau_max)), 1024);
    if (nsub == 1) {
      if (nm == 1) median_depth(st, mem[0], a, b, tsum);
      composite_mix(st, tsum, c, vs, vw, a, b);
    } else {
      bool opaque = false;  /* (a flag, not break: llvmpipe mis-compiled a break here once inlined) */
      for (int s = 0; s < nsub && !opaque; s++) {  /* the same sums per part, each member's erf carried in h_fb */
        float a0 = a + (b - a) * float(s) / float(nsub);
        float a1 = s + 1 < nsub ? a + (b - a) * float(s + 1) / float(nsub) : b;
        tsum = 0.0; vs = 0.0; vw = 0.0; c = vec3(0.0);
        for (int k = 0; k < nm; k++) {
          int h = mem[k];
          if (h_e[h] <= a0 || h_s[h] >= a1) continue;
          float f1 = s + 1 == nsub ? h_fa[h] : erf_at(h, a1);
          float tk = h_c[h] * (f1 - h_fb[h]);
          h_fb[h] = f1;
          tsum += tk; c += tk * h_col[h]; vs += tk * h_val[h]; vw += tk * h_vw[h];
        }
        if (tsum > 0.0) {
          composite_mix(st, tsum, c, vs, vw, a0, a1);
          opaque = st.tr < st.tmin;
        }
      }
    }
  }
  n = 0;
  for (int k = 0; k < nm; k++) {
    int h = mem[k];
    if (h_e[h] > b) { mem[n] = h; n++; } else { slot_free(h); }
  }
  return n;
}

void drop_kept(int n) { for (int k = 0; k < n; k++) { slot_free(mem[k]); } }

/* Consume the entries before horizon; close the cluster when it ends before it. True once the
 * ray is opaque (early termination). */
bool sweep_particles(inout State st, float horizon, float tau_max) {
  bool done = false;
  for (int it = 0; it < 1000000; it++) {
    if (q0 >= nq || !(q_t[q0] < horizon)) break;
    float t = max(q_t[q0], s_last);  /* a chord found late by rounding: starts where the sweep is */
    int h = q_h[q0];
    q0++;
    /* one close per entry at most, called from one place (the cluster ended before this entry,
     * or its interval passed tau_max): llvmpipe mis-compiled two inlined call sites */
    float spread = spread_of();
    bool ended = nm > 0 && t >= s_cend;
    bool full = nm > 0 && !ended && t > s_last && s_last > s_a && s_rho * (t - s_a) * spread > tau_max;
    if (ended || full) {
      float rho;
      int n = close_interval(st, s_a, ended ? s_cend : s_last, spread, tau_max, rho);
      if (ended) { drop_kept(n); nm = 0; } else { nm = n; s_rho = rho; s_a = s_last; }
      if (st.tr < st.tmin) { done = true; break; }
    }
    if (nm == 0) { s_a = t; s_rho = 0.0; s_cend = t; reset_bounds(); }
    h_fa[h] = erf_g(h_sa[h] * (h_s[h] - h_ts[h]));
    widen(h);
    mem[nm] = h;
    nm++;
    s_rho += h_pk[h];
    s_cend = max(s_cend, h_e[h]);
    s_last = t;
  }
  if (!done && nm > 0 && s_cend <= horizon) {  /* no entry before its end is left to find */
    float rho;
    drop_kept(close_interval(st, s_a, s_cend, spread_of(), tau_max, rho));
    nm = 0;
    s_last = s_cend;
    done = st.tr < st.tmin;
  }
  return done;
}

bool trace_tiles(float tn, float tf, inout State st) {
  float tau_max = setting(SET_TAU_MAX), k2 = setting(SET_K) * setting(SET_K);
  ivec3 tb = pixel_tile();
  int tl = tb.x, bit = tb.y;
  int t1 = tile_first(tl + 1);
  slots_start();
  nm = 0;
  s_a = 0.0; s_last = 0.0; s_rho = 0.0; s_cend = -INF;
  reset_bounds();
  int nh = 0, swept = 0, q = tile_first(tl);
  Gauss G;
  vec4 c;
  float aa, qq, ra;
  for (int g = next_hit(q, t1, bit, k2, tn, tf, G, c, aa, qq, ra); g >= 0;
       g = next_hit(q, t1, bit, k2, tn, tf, G, c, aa, qq, ra)) {
    float lbg = entry_bound(G, g);  /* (a horizon at any entry: the entries before it have lower bounds) */
    if (nh >= swept + BATCH && ((q0 < nq && q_t[q0] < lbg) || (nm > 0 && s_cend <= lbg))) {
      swept = nh;
      if (sweep_particles(st, lbg, tau_max)) return true;
    }
    if (nfree == 0) {
      if (sweep_particles(st, lbg, tau_max)) return true;
      if (nfree == 0) return false;
    }
    int h = fre[--nfree];
    h_s[h] = c.x; h_e[h] = c.y; h_ts[h] = c.z; h_pk[h] = c.w;
    h_sa[h] = SQRT_HALF * aa * ra;
    h_c[h] = c.w * SQRT_HALF_PI * ra;
    h_col[h] = g_color(G, g); h_val[h] = G.val; h_vw[h] = G.has_val ? 1.0 : 0.0;
#ifdef LIT
    h_col[h] = lit_chord(G, g, c.z, qq, h_col[h]);
#endif
    queue_insert(c.x, g, h);
    nh++;
  }
  sweep_particles(st, INF, tau_max);
  return true;
}

void trace_mode(Ray r, inout State st)
{
#ifdef LIT
  lit_ray = r;
#endif
  if (!trace_tiles(r.tn, r.tf, st)) {
    st.depth = OVERFLOW_DEPTH;  /* the device draws this pixel's tile on the CPU */
  }
}
