/* One invocation per pixel of the band (row0, col0, nrows x ncols): the camera ray, each
 * object's index ray, the mode's trace_mode, the passes (OVERFLOW_DEPTH where loops_cut). */
void main()
{
  ivec2 p = ivec2(gl_GlobalInvocationID.xy);
  if (p.x >= ncols || p.y >= nrows) {
    return;
  }
  int i = col0 + p.x, j = row0 + p.y;
  Ray r = camera_ray(i, j);
  object_rays(r);
  State st = state_start();
  trace_mode(r, st);
  write_output(p, r, st);
  if (loops_cut()) {  /* the trace may be incomplete: the device draws this tile on the CPU */
    imageStore(out_dv, p, vec4(OVERFLOW_DEPTH, 0.0, 0.0, 0.0));
  }
}
