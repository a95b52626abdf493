/* Paper mode (needs gauss.glsl before it; cpu.pieces.paper_piece): the closest Gaussian entering
 * at or after the current origin (smallest entry, ties by id), fixed midpoint steps over its
 * chord, A = w volfac rho dt, C += T c A, T *= exp(-A), continue after its exit; overlapping
 * Gaussians entered earlier are ignored. The candidates are the screen tile's (lists built for
 * this mode with its weights); a chord counts where the CPU's leaf walk would meet it: entering
 * inside [max(tn, clip start), min(tf, clip end)) of its object. One scan of the tile keeps the
 * KB earliest entries at or after the origin; the next scan starts where they ran out. */
#ifndef KB
#define KB 16
#endif

float b_t0[KB], b_t1[KB];
int b_g[KB];

/* The next of the tile's entries from q (q is left past it) in this pixel's mask whose chord enters
 * in the span counted (see above) at or after pcur, and before the buffer's last when it holds
 * nb == KB: its Gaussian (-1: none left) and chord [e0, e1]. Its own loop, as gauss.glsl's
 * next_hit (llvmpipe's loop budget: loops_cut); with the GPU's lists (their entry bounds in
 * t_lb) a full buffer ends the scan at the first entry bound past its last. */
int next_entry(inout int q, int q1, int bit, float k2, Ray r, float pcur, int nb, out float e0, out float e1)
{
  int found = -1;
  while (found < 0 && q < q1) {
    int g = tile_entry(q, bit);
    q++;
    if (g < 0) {
      continue;
    }
#ifdef GPU_TILES
    if (nb == KB && texel(t_lb, g).x > b_t0[KB - 1]) {  /* lists by entry bound: none later enters sooner */
      q = q1;
      continue;
    }
#endif
    Gauss G = gauss_at(g);
    int ob = n_obj == 1 ? 0 : G.ob;
    vec3 w = (g_ro[ob] - G.mu) * G.iv, v = g_rd[ob] * G.iv;
    float a = dot(v, v);
    float ts = -dot(w, v) / a;
    vec3 p = w + ts * v;
    float qq = dot(p, p);
    if (qq >= k2) {
      continue;
    }
    float hw = sqrt((k2 - qq) / a);
    e0 = max(ts - hw, g_rclip[ob].x);
    e1 = min(ts + hw, g_rclip[ob].y);
    if (!(e1 > e0) || e0 < pcur || e0 < max(r.tn, g_rclip[ob].x) || e0 >= min(r.tf, g_rclip[ob].y)) {
      continue;
    }
    if (nb == KB && !(e0 < b_t0[KB - 1] || (e0 == b_t0[KB - 1] && g < b_g[KB - 1]))) {
      continue;
    }
    found = g;
  }
  return found;
}

void trace_mode(Ray r, inout State st)
{
  float k2 = setting(SET_K) * setting(SET_K);
  int nsteps = int(setting(SET_PAPER_STEPS));
  float maxd = setting(SET_PAPER_DEPTH);
  ivec3 tb = pixel_tile();
  int q0 = tile_first(tb.x), q1 = tile_first(tb.x + 1);
  float pcur = -INF, depth_n = 0.0;
  bool more = true;
  while (more && depth_n < maxd && st.tr >= st.tmin) {
    int nb = 0, q = q0;
    float e0, e1;
    for (int g = next_entry(q, q1, tb.y, k2, r, pcur, nb, e0, e1); g >= 0;
         g = next_entry(q, q1, tb.y, k2, r, pcur, nb, e0, e1)) {
      int j = nb < KB ? nb : KB - 1; /* insert, dropping the last when full */
      while (j > 0 && (e0 < b_t0[j - 1] || (e0 == b_t0[j - 1] && g < b_g[j - 1]))) {
        b_t0[j] = b_t0[j - 1];
        b_t1[j] = b_t1[j - 1];
        b_g[j] = b_g[j - 1];
        j--;
      }
      b_t0[j] = e0;
      b_t1[j] = e1;
      b_g[j] = g;
      nb = min(nb + 1, KB);
    }
    more = nb == KB; /* fewer: every candidate left was in the buffer */
    for (int k = 0; k < nb; k++) {
      if (depth_n >= maxd || st.tr < st.tmin) {
        break;
      }
      if (b_t0[k] < pcur) {
        continue; /* entered inside the last Gaussian drawn */
      }
      int g = b_g[k];
      Gauss G = gauss_at(g);
      int ob = n_obj == 1 ? 0 : G.ob;
      vec3 col = g_color(G, g);
      float val = G.val, vw = G.has_val ? 1.0 : 0.0;
      float dt = (b_t1[k] - b_t0[k]) / float(nsteps);
      for (int s = 0; s < nsteps; s++) {
        float t = b_t0[k] + (float(s) + 0.5) * dt;
        vec3 u = (g_ro[ob] + t * g_rd[ob] - G.mu) * G.iv;
        float A = G.bound * exp(-0.5 * dot(u, u)) * dt;
        float T = st.tr;
        st.rad += T * col * A;
        if (vw > 0.0) {
          st.vsum += T * A * val;
          st.vwt += T * A;
        }
        st.tr = T * exp(-A);
        if (st.depth == BG_DEPTH && st.tr <= 0.5) {
          st.depth = t;
        }
      }
      depth_n += 1.0;
      pcur = b_t1[k];
    }
  }
}
