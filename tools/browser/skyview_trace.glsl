// Debug fragment shader (tools/browser/skyview_trace.mjs; not part of the viewer): the
// intermediate quantities of web/lut/skyview.glsl's SkyViewRadiance for one sky query, one
// scalar per pixel of an N x 1 float framebuffer, in the order
// crates/harness/examples/skyview_trace.rs prints the reader's (SkyViewReader::scattering).
// Appended after atmosphere.glsl and skyview.glsl (SKYVIEW_LAYOUT defined, neither SKY_VIEW nor
// PROBES), it repeats SkyViewRadiance's steps with that file's own functions, so the first
// quantity that differs from the reader's locates the deviation.
uniform vec3 trace_camera;
uniform vec3 trace_view;
uniform vec3 trace_sun;
out vec4 frag_value;

int trace_target;
int trace_count;
float trace_value;

void T(float x) {
  if (trace_count == trace_target) trace_value = x;
  trace_count++;
}
void T3(vec3 v) { T(v.x); T(v.y); T(v.z); }
void TS(SvStencil s) {
  T(float(s.first)); T(float(s.len)); T(s.w[0]); T(s.w[1]); T(s.w[2]); T(s.w[3]);
}

void main() {
  trace_target = int(gl_FragCoord.x);
  trace_count = 0;
  trace_value = 0.0;
  // GetSkyRadiance (the camera inside the atmosphere).
  vec3 camera = trace_camera;
  vec3 view_ray = normalize(trace_view);
  vec3 sun_direction = normalize(trace_sun);
  float r0 = length(camera);
  float h0 = max(r0 - bottom_radius, 0.0);
  float rho = sqrt(h0 * (2.0 * bottom_radius + h0));
  vec3 up = camera / r0;
  // SkyViewRadiance.
  float h = clamp(h0, 0.0, top_radius - bottom_radius);
  float r = bottom_radius + h;
  float mu = clamp(dot(view_ray, up), -1.0, 1.0);
  float mu_s = clamp(dot(sun_direction, up), -1.0, 1.0);
  float nu = dot(view_ray, sun_direction);
  T(h); T(mu); T(mu_s); T(nu);
  int segment;
  float row;
  float dip = atan(rho, bottom_radius);
  float gamma = 0.0, dip_t = 0.0, h_t = h, y_limb = 0.0;
  if (mu >= 0.0) {
    segment = 0;
    row = 0.0;
  } else if (mu > -rho / r) {
    segment = 1;
    float r_minus_rt = r * mu * mu / (1.0 + sqrt(1.0 - mu * mu));
    y_limb = h > 0.0 ? clamp(r_minus_rt / h, 0.0, 1.0) : 1.0;
    row = float(SV_N_VIEW_SKY) + SkyViewLimbRow(y_limb) * float(SV_N_VIEW_LIMB - 1);
    h_t = max(h - r_minus_rt, 0.0);
    gamma = asin(-mu);
    dip_t = atan(sqrt(h_t * (2.0 * bottom_radius + h_t)), bottom_radius);
  } else {
    segment = 2;
    float x = sqrt(clamp((asin(-mu) - dip) / (0.5 * PI - dip), 0.0, 1.0));
    row = float(SV_N_VIEW_UP) + x * float(SV_N_VIEW_DOWN - 1);
  }
  vec3 view_h = view_ray - mu * up;
  vec3 sun_h = sun_direction - mu_s * up;
  float phi = dot(view_h, view_h) * dot(sun_h, sun_h) > 1e-12 ?
      atan(length(cross(view_h, sun_h)), dot(view_h, sun_h)) : 0.0;
  T(phi); T(SkyViewAzimuthColumn(phi, h));
  float shift = dip;
  if (segment == 1) {
    float w = SkyViewLimbTangentWeight(SkyViewCos(phi), h, h - h_t);
    shift = dip + w * (gamma * SkyViewCos(phi) + dip_t - dip);
  } else if (segment == 0) {
    float w = smoothstep(SV_SKY_EXIT_ALTITUDE.x, SV_SKY_EXIT_ALTITUDE.y, h);
    float toward = SkyViewExitAzimuth(SkyViewCos(phi));
    if (w > 0.0 && toward != 0.0) {
      float x_top = DistanceToTopAtmosphereBoundary(r, mu);
      float exit_angle = atan(x_top * sqrt(max(1.0 - mu * mu, 0.0)), r + x_top * mu);
      shift = dip + w * exit_angle * toward;
    }
  }
  float band_c = 0.0, band_k = 0.0, elevation = 0.0;
  float s_q = degrees(asin(mu_s) + shift);
  T(float(segment)); T(y_limb); T(shift); T(s_q);
  if (segment < 2) {
    SkyViewBandFocus(s_q, h, band_c, band_k);
    elevation = degrees(asin(mu));
  }
  T(band_c); T(band_k);
  if (segment == 0) {
    row = SkyViewSkyRow(elevation, band_c * SkyViewFocusPlace(band_c, h), band_k,
                        SkyViewFocusWidth(band_c, h)) *
        float(SV_N_VIEW_SKY - 1);
  }
  int lo = segment == 0 ? 0 : segment == 1 ? SV_N_VIEW_SKY : SV_N_VIEW_UP;
  int hi = segment == 0 ? SV_N_VIEW_SKY - 1 : segment == 1 ? SV_N_VIEW_UP - 1 : SV_N_VIEW - 1;
  SvStencil sv = SkyViewStencil(row, lo, hi, false, 0.0);
  // (The query's own limb row as the reader's view_coord forms it: focused at the query's sun
  // and altitude; each slice's is traced below.)
  float row_q = row;
  if (segment == 1) {
    vec2 f = SkyViewLimbFocus(s_q, h);
    row_q = float(SV_N_VIEW_SKY) +
        SkyViewFocusCoord(SkyViewLimbRow(y_limb), f.x, f.y) * float(SV_N_VIEW_LIMB - 1);
  }
  T(row_q);
  TS(SkyViewStencil(row_q, lo, hi, false, 0.0));
  int k0, j0;
  float tk, tj, above_deg;
  SkyViewAltitudeSun(h, shift, SkyViewSunWarpCentre(h, segment, SkyViewCos(phi)), mu_s, k0, tk,
                     j0, tj, above_deg);
  SvStencil sa = SkyViewAltitudeStencil(float(k0) + tk);
  SvStencil ss_q = SkyViewStencil(float(j0) + tj, 0, SV_N_SUN - 1, true, above_deg);
  T(float(k0) + tk); T(above_deg); T(float(j0) + tj);
  TS(sa);
  TS(ss_q);
  float d;
  if (segment == 2) {
    float disc = max(r * mu * r * mu - rho * rho, 0.0);
    float den = -r * mu + sqrt(disc);
    d = den > 0.0 ? rho * rho / den : 0.0;
  } else {
    d = DistanceToTopAtmosphereBoundary(r, mu);
  }
  T(d);
  vec3 parts[2];
  for (int part = 0; part < 2; ++part) {
    vec3 by_altitude[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
    for (int a = 0; a < 4; ++a) {
      if (a >= sa.len) break;
      vec3 by_sun[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
      float column_q = SkyViewAzimuthColumn(phi, h);
      float node_read = smoothstep(SV_AZ_NODE_READ.x, SV_AZ_NODE_READ.y, h);
      float column = node_read > 0.0 ?
          column_q + node_read * (SkyViewAzimuthColumn(phi, sv_alt_nodes[sa.first + a]) - column_q) :
          column_q;
      SvStencil sc = SkyViewColumnStencil(column);
      T(column);
      TS(sc);
      // On the limb rows, the node read at the query's sun coordinate formed with the node's
      // tangent-point weight, aloft with the query's (SkyViewLimbNodeShift), without the sun
      // nodes read too deep.
      SvStencil ss = ss_q;
      float s_k = s_q;
      if (segment == 1) {
        float h_n = sv_alt_nodes[sa.first + a];
        float cos_phi = SkyViewCos(phi);
        float shift_n = SkyViewLimbNodeShift(h, h_n, y_limb, cos_phi, gamma, dip, dip_t, h_t);
        s_k = degrees(asin(mu_s) + shift_n);
        float above_n = SkyViewSunAbove(h, shift_n, SkyViewSunWarpCentre(h, segment, cos_phi), mu_s);
        SvStencil ss_n = SkyViewStencil(SkyViewSunCoord(above_n), 0, SV_N_SUN - 1, true, above_n);
        ss = SkyViewLimbSunStencil(ss_n, y_limb, s_k, h, h_n, above_n);
      }
      T(s_k);
      TS(ss);
      vec4 cos_cols;
      for (int m = 0; m < 4; ++m) {
        int col = SkyViewColumnTexel(sc.first + m);
        float cos_n = sv_az_node_cos[(sa.first + a) * SV_N_AZ + col];
        cos_cols[m] = node_read >= 1.0 || segment == 2 ? cos_n :
            node_read > 0.0 ? (1.0 - node_read) * SkyViewCos(SkyViewAzimuthNode(col, h)) + node_read * cos_n :
            SkyViewCos(SkyViewAzimuthNode(col, h));
      }
      for (int s = 0; s < 4; ++s) {
        if (s >= ss.len) break;
        int k = sa.first + a, j = ss.first + s;
        float h_n = sv_alt_nodes[k];
        float b_n = SkyViewWarpStrength(h_n);
        float s_n = SkyViewSunWarp(SkyViewSunNodeDeg(j), b_n);
        vec3 value;
        SvStencil band_rows[4];
        bool band = segment < 2 && SkyViewBandRows(elevation, band_c, band_k, s_q, h, SkyViewCos(phi),
                                                   cos_cols, k, j, band_rows);
        T(h_n); T(s_n); T(band ? 1.0 : 0.0);
        if (band) {
          T(SkyViewBandSlice(elevation, s_q, SkyViewBandWeight(s_q, h), h, s_n, h_n,
                             SkyViewCos(phi)));
          for (int m = 0; m < 4; ++m) {
            if (m >= sc.len) break;
            TS(band_rows[m]);
          }
          value = part == 0 ? SkyViewFetchBand(skyview_rayleigh, k, j, sc, band_rows) :
                              SkyViewFetchBand(skyview_mie, k, j, sc, band_rows);
        } else {
          SvStencil sv_n = sv;
          if (segment == 1) {
            vec2 limb_n = SkyViewLimbFocus(s_n, h_n);
            float y_n = SkyViewLimbSliceDepth(y_limb, s_k, h, s_n, h_n);
            float yr = float(SV_N_VIEW_SKY) +
                SkyViewFocusCoord(SkyViewLimbRow(y_n), limb_n.x, limb_n.y) *
                    float(SV_N_VIEW_LIMB - 1);
            T(y_n); T(yr);
            sv_n = SkyViewStencil(yr, lo, hi, false, 0.0);
          }
          for (int m = 0; m < 4; ++m) {
            if (m >= sc.len) break;
            TS(sv_n);
          }
          vec3 by_row[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
          for (int v = 0; v < 4; ++v) {
            if (v >= sv_n.len) break;
            int y = sv_n.first + v;
            by_row[v] = part == 0 ? SkyViewFetch(skyview_rayleigh, k, j, y, sc) :
                                    SkyViewFetch(skyview_mie, k, j, y, sc);
          }
          value = SkyViewMix(sv_n, by_row);
        }
        T3(value);
        ivec2 slice = ivec2(j, k);
        vec3 scale = part == 0 ? texelFetch(skyview_scale_rayleigh, slice, 0).rgb :
                                 texelFetch(skyview_scale_mie, slice, 0).rgb;
        T3(scale);
        by_sun[s] = value * scale;
      }
      by_altitude[a] = SkyViewMix(ss, by_sun);
      T3(by_altitude[a]);
    }
    parts[part] = SkyViewMix(sa, by_altitude) * d;
    T3(parts[part]);
  }
  T3(parts[0]);
  T3(parts[1]);
  T3(parts[0] * RayleighPhaseFunction(nu) + parts[1] * AerosolPhaseFunction(nu));
  frag_value = vec4(trace_value, float(trace_count), 0.0, 1.0);
}
