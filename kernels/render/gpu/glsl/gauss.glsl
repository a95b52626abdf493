/* The Gaussian modes' shared pieces (particles, field, paper): the per-Gaussian tables, the
 * screen-tile lists (gpu.tables_gauss), erf, and the exact ray/support test (cpu.chords.chord).
 * Float32 throughout; the CPU device's float64 image is matched within 50 dB, not bit for bit. */

/* Gaussian g (gpu.tables_gauss.gauss_tables, GREC_SIZE floats): centre, entry bound (or paper's
 * w x volfac), 1/sigma (18-bit floats: size_words), weight w, value (0 when none), whether it
 * has a value, object */
struct Gauss { vec3 mu; float bound; vec3 iv; float w, val; bool has_val; int ob; };
/* float e (< 8) of a record held in the two texels a, b */
float in2(vec4 a, vec4 b, int e)
{
  return e < 4 ? a[e & 3] : b[e & 3];
}
Gauss gauss_at(int g)
{
  vec4 a = texel(g_rec, 2 * g), b = texel(g_rec, 2 * g + 1);  /* GREC_SIZE == 8 */
  uint x = floatBitsToUint(in2(a, b, GREC_WORDS)), y = floatBitsToUint(in2(a, b, GREC_WORDS + 1));
  uvec3 code = (uvec3(x >> 16, x & 0xffffu, y >> 16) << 3) | (uvec3(y, y >> 3, y >> 6) & 7u);
  Gauss G;
  G.mu = vec3(in2(a, b, GREC_MU), in2(a, b, GREC_MU + 1), in2(a, b, GREC_MU + 2));
  G.bound = in2(a, b, GREC_BOUND);
  G.iv = uintBitsToFloat((code + (uint(EXP_REBIAS) << 13)) << MANT_DROP);
  G.w = in2(a, b, GREC_W);
  G.val = in2(a, b, GREC_VAL);
  G.has_val = ((y >> 13) & 1u) != 0u;
  G.ob = int((y >> 9) & 15u);
  return G;
}
/* Gaussian g's colour (_cpu's per-frame colours: the LUT at its value, or the colour map at its
 * colour value; level sets: ls_color at the centre) */
vec3 g_color(Gauss G, int g)
{
  int ob = n_obj == 1 ? 0 : G.ob;
  if (g_kind[ob] != KIND_FOG) {
    return ls_color(ob, g_tfi[ob], G.mu);
  }
#ifdef COLOR_VALUES
  if (color_tf(ob) >= 0) {
    return color_map(color_tf(ob), scalar(g_cval, g));
  }
#endif
  return G.has_val ? lut_at(g_tfi[ob], tf_x(G.val, g_par[ob])).rgb : vec3(0.0);
}

#ifdef LIT
Ray lit_ray;  /* the pixel's world ray, for lit volumes' shading (common.glsl's shade_sample) */
#endif

#ifdef GPU_TILES
float entry_bound(Gauss G, int g) { return texel(t_lb, g).x; }  /* lists built on the GPU (tiles.glsl) */
#else
float entry_bound(Gauss G, int g) { return G.bound; }
#endif
int tile_first(int tl) { return int(scalar(t_start, tl)); }
/* entry q of the tile lists: its Gaussian, or -1 when pixel bit `bit` is not in its mask */
int tile_entry(int q, int bit) {
  vec4 e = texel(t_ent, q);  /* TENT_SIZE == 4 */
  int piece = bit / MASK_BITS;
  int m = int(piece == 0 ? e[TENT_MASK] : (piece == 1 ? e[TENT_MASK + 1] : e[TENT_MASK + 2]));
  return ((m >> (bit - MASK_BITS * piece)) & 1) != 0 ? int(e[TENT_ID]) : -1;
}

/* erfc with fractional error < 1.2e-7 everywhere (Numerical Recipes' Chebyshev fit) */
float erfc_g(float x) {
  float z = abs(x);
  float t = 1.0 / (1.0 + 0.5 * z);
  float r = t * exp(-z * z - 1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418
            + t * (-0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587
            + t * (-0.82215223 + t * 0.17087277)))))))));
  return x >= 0.0 ? r : 2.0 - r;
}
float erf_g(float x) { return 1.0 - erfc_g(x); }
/* erf(u1) - erf(u0), u0 <= u1, h = u1 - u0 formed by the caller (see cpu.vecmath.erf_span) */
float erf_span(float u0, float u1, float h) {
  float m = 0.5 * (u0 + u1);
  if (h * max(1.0, abs(m)) < 1e-2) {
    float m2 = m * m, h2 = h * h;
    float series = 1.0 + (4.0 * m2 - 2.0) * h2 / 24.0 + (16.0 * m2 * m2 - 48.0 * m2 + 12.0) * h2 * h2 / 1920.0;
    return TWO_OVER_SQRT_PI * h * exp(-m2) * series;
  }
  if (u0 >= 0.0) return erfc_g(u0) - erfc_g(u1);
  if (u1 <= 0.0) return erfc_g(-u1) - erfc_g(-u0);
  return erf_g(u1) - erf_g(u0);
}

/* Gaussian G against the index-space ray o + t d (cpu.chords.chord): returns (s, e, ts, pk)
 * with the chord clipped to [tn, tf] (a miss: s >= e); aa = |d'|^2, qq its closest squared
 * distance, ra = 1 / |d'|. */
vec4 chord(Gauss G, vec3 o, vec3 d, float k2, float tn, float tf, out float aa, out float qq, out float ra) {
  vec3 w = (o - G.mu) * G.iv;
  vec3 v = d * G.iv;
  aa = dot(v, v);
  float ia = 1.0 / aa;
  float ts = -dot(w, v) * ia;
  vec3 p = w + ts * v;
  qq = dot(p, p);
  ra = sqrt(ia);
  float hw = sqrt(max(k2 - qq, 0.0)) * ra;
  float s = qq < k2 ? max(ts - hw, tn) : INF;
  float pk = G.w * exp(-0.5 * min(qq, k2));
  return vec4(s, min(ts + hw, tf), ts, pk);
}

/* The next of the tile's entries from q (q is left past it) in this pixel's mask whose chord meets
 * [tn, tf] and its object's clip interval: its Gaussian (-1: none left), the chord as chord()
 * gives it. The misses are skipped in this loop of its own: in the callers' loop each pass would
 * also run their sweeps' loops once on llvmpipe (see loops_cut), which dense tiles (thousands of
 * entries) could not afford. */
int next_hit(inout int q, int q1, int bit, float k2, float tn, float tf, out Gauss G, out vec4 c,
             out float aa, out float qq, out float ra)
{
  int found = -1;
  while (found < 0 && q < q1) {
    int g = tile_entry(q, bit);
    q++;
    if (g >= 0) {
      G = gauss_at(g);
      int ob = n_obj == 1 ? 0 : G.ob;
      c = chord(G, g_ro[ob], g_rd[ob], k2, max(tn, g_rclip[ob].x), min(tf, g_rclip[ob].y), aa, qq, ra);
      found = c.y > c.x ? g : -1;
    }
  }
  return found;
}

/* -- the hits of one ray (particles, field): PCAP slots, a free list and the entry queue ----- */
#ifndef PCAP
#define PCAP 160
#endif
#ifndef BATCH
#define BATCH 32
#endif
float q_t[PCAP];  /* entry queue [q0, nq), sorted by (t, Gaussian id): times, ids, slots */
int q_g[PCAP], q_h[PCAP];
int fre[PCAP];
int q0, nq, nfree;

void slots_start()
{
  q0 = 0;
  nq = 0;
  nfree = PCAP;
  for (int k = 0; k < PCAP; k++) {
    fre[k] = PCAP - 1 - k;
  }
}

void slot_free(int h)
{
  fre[nfree] = h;
  nfree++;
}

/* from the back (cpu.chords.queue_insert): entries arrive nearly in order */
void queue_insert(float t, int g, int h)
{
  if (nq == PCAP) { /* the head has moved on: shift the queue down (a slot was free: room) */
    for (int k = q0; k < nq; k++) {
      q_t[k - q0] = q_t[k];
      q_g[k - q0] = q_g[k];
      q_h[k - q0] = q_h[k];
    }
    nq -= q0;
    q0 = 0;
  }
  int j = nq;
  while (j > q0 && (t < q_t[j - 1] || (t == q_t[j - 1] && g < q_g[j - 1]))) {
    q_t[j] = q_t[j - 1];
    q_g[j] = q_g[j - 1];
    q_h[j] = q_h[j - 1];
    j--;
  }
  q_t[j] = t;
  q_g[j] = g;
  q_h[j] = h;
  nq++;
}

/* the ray's screen tile and its bit in the tile's pixel masks */
ivec3 pixel_tile()
{
  ivec2 p = ivec2(gl_GlobalInvocationID.xy) + ivec2(col0, row0);
  int ntx = (int(cam(CAM_W)) + TILE - 1) / TILE;
  return ivec3((p.y / TILE) * ntx + p.x / TILE, (p.y % TILE) * TILE + p.x % TILE, 0);
}
