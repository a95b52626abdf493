/* Volumes coloured by a second grid (cpu.vecmath.recolor; tables: gpu.tables_color): the sample's
 * colour from the object's colour map at the second grid's value, its extinction and value
 * still its own grid's. COLOR_GRID: obj_color; COLOR_VALUES: g_cval (particles, paper). */
#ifdef COLOR_GRID
/* object ob's colour map (its transfer-function row; -1: coloured by its own grid) */
int color_tf(int ob)
{
  return int(texel(obj_color, ob)[OCOL_CTF]);
}

/* the colour grid's background: its value where no Gaussian is (field mode's second mixture) */
float color_background(int ob)
{
  return texel(obj_color, ob)[OCOL_CBG];
}

/* colour map c at value cv (NaN: black) */
vec3 color_map(int c, float cv)
{
  float x = tf_x(cv, texel(tf_par, c));
  return isnan(x) ? vec3(0.0) : lut_at(c, x).rgb;
}

/* a sample of extinction sig: its colour from ob's colour map at cv, if it has one */
void recolor(int ob, float cv, float sig, inout vec3 col)
{
  int c = color_tf(ob);
  if (c >= 0 && sig > 0.0) {
    col = color_map(c, cv);
  }
}
#endif
