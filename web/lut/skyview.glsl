// skybake's `skyview` layout (docs/lut.md, "The skyview layout") in GLSL ES 3.0 (WebGL2): the
// sky, the aerial perspective and the sun and sky light with the signatures and meaning of
// Bruneton's GetSkyRadiance, GetSkyRadianceToPoint(Offset) and GetSunAndSkyIrradiance
// (Bruneton 2017, functions.glsl), so a renderer switches layout without changing its calls.
// A port of skybake_lut::SkyViewReader (crates/lut/src/skyview.rs, `skybake lut-eval`), which
// is its specification; tools/browser/lut_test.mjs checks one against the other.
//
// Appended after atmosphere.glsl, compiled with SKYVIEW_LAYOUT defined: that file then leaves
// out Bruneton's scattering and irradiance lookups and declares these three functions, and this
// one uses its transmittance functions (Bruneton's transmittance texture, the same in both
// layouts), its RhoAlong and SquareDifference, and the Rayleigh phase function. The including
// program defines the node counts from the manifest's parameterisation.sizes: SV_N_ALT,
// SV_N_SUN, SV_N_VIEW_SKY, SV_N_VIEW_LIMB, SV_N_VIEW_DOWN, SV_N_AZ, and SV_N_SUN_SEGMENTS (the
// length of parameterisation.sun_segments), SV_LIMB_SHADOW_SCALE
// (parameterisation.limb_shadow_scale_m, a float literal), SV_SUN_WARP
// (parameterisation.sun_warp_strength) and SV_SUN_WARP_LO, SV_SUN_WARP_HI
// (parameterisation.sun_warp_range), float literals, and from parameterisation.sky_row_band:
// SV_BAND_SUN (sun_deg), SV_BAND_FOCUS (focus), SV_BAND_CENTRE (centre, a vec4),
// SV_BAND_SUN_RANGE (sun_range_deg, a vec4), SV_BAND_ALTITUDE (altitude_range_m, a vec2),
// SV_BAND_CENTRE_RANGE (centre_range_deg, a vec2), SV_BAND_CENTRE_FLOOR (centre_floor),
// SV_BAND_ANTISOLAR (antisolar), SV_BAND_DEPTH (depth_deg_per_km), SV_BAND_HORIZON
// (horizon_deg), SV_BAND_ANTISOLAR_RANGE (antisolar_range, a vec2), SV_BAND_GROWTH
// (focus_growth), SV_BAND_GROWTH_ALTITUDE (focus_growth_altitude_m, a vec2),
// SV_BAND_CENTRE_ALOFT (centre_aloft_per_km), SV_BAND_CENTRE_ALOFT_ALTITUDE
// (centre_aloft_altitude_m, a vec2), SV_BAND_CENTRE_TOP (vec2(centre_top_altitude_m,
// centre_top_per_km)), SV_BAND_SLICE_ALOFT (slices_aloft_per_km, a vec2),
// SV_BAND_SLICE_TOP (slices_top_per_km), SV_BAND_SLICE_THROUGH (slices_through_altitude_m, a
// vec2), SV_BAND_SLICE_AZIMUTH (slices_azimuth_altitude_m, a vec2), SV_BAND_DEPTH_TOP
// (depth_top_m), SV_BAND_FOCUS_ALOFT
// (focus_aloft), SV_BAND_FOCUS_ALOFT_ALTITUDE (focus_aloft_altitude_m, a vec2),
// SV_BAND_FOCUS_PLACE_ALOFT (focus_place_aloft), SV_BAND_FOCUS_PLACE_ALTITUDE
// (focus_place_altitude_m, a vec2), SV_BAND_FOCUS_HIGH (focus_high), SV_BAND_FOCUS_WIDTH_AZIMUTH
// (focus_width_azimuth_cos), SV_BAND_FOCUS_WIDTH_FLOOR (focus_width_floor_deg),
// SV_BAND_FOCUS_WIDTH_ALTITUDE (focus_width_altitude_m, a vec4), SV_BAND_FOCUS_WIDE (focus_wide),
// SV_BAND_SUN_SOFT (sun_soft_deg),
// SV_BAND_AZIMUTH_DEPTH_ALOFT (azimuth_depth_aloft_deg), SV_BAND_AZIMUTH_DEPTH_ALTITUDE
// (azimuth_depth_aloft_altitude_m, a vec2), and SV_ALT_NODES
// (parameterisation.altitude_nodes_m, a float[SV_N_ALT] constructor), SV_ALT_X
// (parameterisation.altitude_node_abscissas, a float[SV_N_ALT] constructor); from
// parameterisation.limb_row_band: SV_LIMB_BAND_DEPTH (depth_m, a vec3), SV_LIMB_BAND_FOCUS
// (focus), SV_LIMB_BAND_SUN_RANGE (sun_range_deg, a vec4), SV_LIMB_BAND_ALTITUDE
// (altitude_range_m, a vec4), SV_LIMB_BAND_DEPTH_FLOOR (depth_floor_m),
// SV_LIMB_BAND_ALTITUDE_EXPONENT (altitude_exponent), SV_LIMB_BAND_MAX_FRACTION (max_fraction),
// SV_LIMB_BAND_HORIZON_HELD (horizon_held, a vec2), SV_LIMB_BAND_DEEPEST (deepest),
// SV_LIMB_EDGE_DEPTH (edge_depth_m, a vec2), SV_LIMB_EDGE_FOCUS (edge_focus),
// SV_LIMB_EDGE_SUN_RANGE (edge_sun_range_deg, a vec4), SV_LIMB_EDGE_ALTITUDE
// (edge_altitude_range_m, a vec4);
// from parameterisation.azimuth_aloft: SV_AZ_WEIGHT (weight), SV_AZ_GROUND_WEIGHT
// (ground_weight) and SV_AZ_ALTITUDE (altitude_range_m, a vec2); from parameterisation.azimuth_focus: SV_AZ_FOCUS (vec3(weight,
// centre_deg, width_deg)), SV_AZ_FOCUS_ALTITUDE (altitude_range_m, a vec2) and SV_AZ_NODE_READ
// (node_read_altitude_m, a vec2); SV_AZ_NODE_COS
// (the cosines of parameterisation.azimuth_nodes_rad, a float[SV_N_ALT * SV_N_AZ] constructor,
// altitude node k's columns at k * SV_N_AZ ..), SV_ALT_MAP (parameterisation.altitude_map, a vec3) and
// SV_SKY_EXIT_ALTITUDE (parameterisation.sky_exit_altitude_m, a vec2), SV_SKY_EXIT_AZIMUTH_FADE
// (parameterisation.sky_exit_azimuth_fade); SV_SUN_WARP_CENTRE and
// SV_SUN_WARP_CENTRE_ALTITUDE (parameterisation.sun_warp_centre: weight, altitude_range_m, a
// vec2); from
// parameterisation.limb_near_end: SV_LIMB_NEAR_END_AZIMUTH (azimuth_cos, a vec2),
// SV_LIMB_NEAR_END_DEPTH (depth_m, a vec2), SV_LIMB_NEAR_END_ALTITUDE (altitude_range_m, a vec2),
// SV_LIMB_NODE_WEIGHT_ALTITUDE (node_weight_altitude_m, a vec2), SV_LIMB_NODE_QUERY_WEIGHT
// (node_query_weight_altitude_m, a vec2).
//
// Per query: node coordinates in altitude (the base abscissa (sqrt(e) + c (e^p - e^q)) x_last
// within the nodes' abscissas SV_ALT_X,
// e = h / thickness), the sun's elevation above the observer's horizon (the manifest's
// segments), the view row within its segment (sky, limb, below the horizon; relative to the
// observer's horizon) and the azimuth from the sun's, at each altitude node in the node's own
// map (sqrt(phi / pi) (N_AZ - 1) near the ground, blended with sin^2(phi / 2) and a focus at
// 115 degrees aloft); over the 4 columns, the up to 4 rows (times the
// slice's scale), 4 sun and 4 altitude nodes around it, the Lagrange polynomial of the values' logarithms
// (SkyViewStencil, SkyViewMix; geometric a^(1-t) b^t between two nodes where a value is not
// positive); on the limb rows the sun coordinate moves towards the sun's elevation above the
// horizon of the ray's tangent point; times the ray's length (the textures hold radiance per
// metre of ray) and the exact phase functions. Fetching texels (not the GPU's filtering, whose weights many GPUs round to 8 bits)
// makes the result the same on every device. 32-bit floats: the altitude, the horizon's dip and
// the limb row are computed from the altitude h and rho = sqrt(h (2 R + h)), not from ratios of
// radii near 1, and the azimuth from the horizontal components of the view and the sun (atan),
// not from acos of a cosine near 1.

// ---- the bundle's skyview textures (web/lut/sky.js uploads them) ----
// The rayleigh and mie textures, their 28 x 75 slices tiled in one 2-D texture: slice
// (altitude k, sun j) at columns j N_AZ .. and rows k N_VIEW .. (RGBA16F, the files' half floats).
uniform sampler2D skyview_rayleigh;
uniform sampler2D skyview_mie;
// Per-slice scales (N_SUN x N_ALT, RGB) of the two parts, and the sky irradiance table
// (N_SUN x N_ALT, RGB: irradiance on a horizontal surface / (top - r)).
uniform sampler2D skyview_scale_rayleigh;
uniform sampler2D skyview_scale_mie;
uniform sampler2D skyview_irradiance;
// parameterisation.sun_segments: (start deg, step deg, intervals).
uniform vec3 skyview_sun_segments[SV_N_SUN_SEGMENTS];
// aerosol_phase_function: kind 0 cornette_shanks, 1 henyey_greenstein, 2 mixture, 3 isotropic,
// 4 rayleigh; its g and rayleigh_fraction.
uniform int aerosol_phase_kind;
uniform float aerosol_g;
uniform float aerosol_rayleigh_fraction;

const int SV_N_VIEW_UP = SV_N_VIEW_SKY + SV_N_VIEW_LIMB;
const int SV_N_VIEW = SV_N_VIEW_UP + SV_N_VIEW_DOWN;

float CornetteShanksPhase(float g, float nu) {
  float d = max(1.0 + g * g - 2.0 * g * nu, 1e-12);
  return 3.0 / (8.0 * PI) * (1.0 - g * g) * (1.0 + nu * nu) / ((2.0 + g * g) * d * sqrt(d));
}

// The aerosol's phase function, as the manifest names it (skybake's Phase::eval).
float AerosolPhaseFunction(float nu) {
  nu = clamp(nu, -1.0, 1.0);
  float g = aerosol_g;
  if (aerosol_phase_kind == 0) return CornetteShanksPhase(g, nu);
  if (aerosol_phase_kind == 1) {
    float d = max(1.0 + g * g - 2.0 * g * nu, 1e-12);
    return (1.0 - g * g) / (4.0 * PI * d * sqrt(d));
  }
  if (aerosol_phase_kind == 2) {
    return (1.0 - aerosol_rayleigh_fraction) * CornetteShanksPhase(g, nu) +
        aerosol_rayleigh_fraction * RayleighPhaseFunction(nu);
  }
  if (aerosol_phase_kind == 3) return 1.0 / (4.0 * PI);
  return RayleighPhaseFunction(nu);
}

// Node index (the lower of two) and fraction of the continuous node coordinate x over n nodes.
int SkyViewSplit(float x, int n, out float t) {
  x = clamp(x, 0.0, float(n - 1));
  int i = min(int(floor(x)), n - 2);
  t = x - float(i);
  return i;
}

// Geometric interpolation a^(1-t) b^t per channel; linear where a value is not positive.
vec3 GeoMix(vec3 a, vec3 b, float t) {
  if (t <= 0.0) return a;
  if (t >= 1.0) return b;
  vec3 geometric = a * exp2(t * log2(max(b, vec3(1e-30)) / max(a, vec3(1e-30))));
  vec3 positive = vec3(greaterThan(min(a, b), vec3(0.0)));
  return mix(mix(a, b, t), geometric, positive);
}

// Interpolation along one node axis (SkyViewReader's Stencil): the nodes first .. first + len - 1
// (up to 4) around the continuous node coordinate y within the axis segment lo..hi, their
// Lagrange weights w at the query's abscissa xq (the nodes' abscissas from SkyViewAbscissa), the
// interval's lower node i0 and fraction t.
struct SvStencil {
  int first;
  int len;
  vec4 w;
  int i0;
  float t;
};

// Sun node j's elevation above the observer's horizon (degrees), from the manifest's segments.
float SkyViewSunNodeDeg(int j) {
  int first = 0;
  for (int s = 0; s < SV_N_SUN_SEGMENTS; ++s) {
    vec3 seg = skyview_sun_segments[s];
    int n = int(seg.z);
    if (j <= first + n) return seg.x + float(j - first) * seg.y;
    first += n;
  }
  vec3 last = skyview_sun_segments[SV_N_SUN_SEGMENTS - 1];
  return last.x + last.z * last.y;
}

// Lagrange weights at xq over the nodes x[0..len) (0 beyond len).
vec4 SkyViewLagrange(float xq, float x[4], int len) {
  vec4 w = vec4(0.0);
  for (int m = 0; m < 4; ++m) {
    if (m >= len) break;
    float p = 1.0;
    for (int n = 0; n < 4; ++n) {
      if (n >= len) break;
      if (n != m) p *= (xq - x[n]) / (x[m] - x[n]);
    }
    w[m] = p;
  }
  return w;
}

// The stencil of y in lo..hi; sun_axis: the abscissa is the node's elevation (degrees, xq the
// query's), else the node index (xq = y).
SvStencil SkyViewStencil(float y, int lo, int hi, bool sun_axis, float xq) {
  SvStencil st;
  y = clamp(y, float(lo), float(hi));
  st.i0 = clamp(int(floor(y)), lo, hi - 1);
  st.t = y - float(st.i0);
  st.first = max(st.i0 - 1, lo);
  int last = min(st.i0 + 2, hi);
  st.len = last - st.first + 1;
  if (!sun_axis) xq = y;
  float x[4];
  for (int m = 0; m < 4; ++m) {
    int i = min(st.first + m, last);
    x[m] = sun_axis ? SkyViewSunNodeDeg(i) : float(i);
  }
  st.w = vec4(0.0);
  if (st.t == 0.0) {
    st.w[st.i0 - st.first] = 1.0;
    return st;
  }
  st.w = SkyViewLagrange(xq, x, st.len);
  return st;
}

// The columns' stencil at column coordinate `column` (the reader's column_stencil): over the
// columns continued by their mirror images past the sun and the antisolar point (the sky is
// symmetric about the sun's vertical plane), node v being column v - 1 (SkyViewColumnTexel), so
// a query in the first or last column interval gets a cubic centred on its interval.
SvStencil SkyViewColumnStencil(float column) {
  return SkyViewStencil(column + 1.0, 0, SV_N_AZ + 1, false, 0.0);
}

// The texel column of node v of SkyViewColumnStencil: v - 1 reflected into 0 .. SV_N_AZ - 1.
int SkyViewColumnTexel(int v) {
  int a = v - 1;
  return a < 0 ? -a : a > SV_N_AZ - 1 ? max(2 * (SV_N_AZ - 1) - a, 0) : a;
}

// The stencil's interpolation of its node values v[0 .. len - 1], per channel: the Lagrange
// polynomial of their logarithms, bounded by the values' range; where a value is not positive,
// GeoMix between the interval's two nodes.
vec3 SkyViewMix(SvStencil st, vec3 v[4]) {
  vec3 a = v[st.i0 - st.first];
  vec3 b = v[st.i0 - st.first + 1];
  if (st.t == 0.0) return a;
  vec3 lo = a, hi = a, ln = vec3(0.0);
  for (int m = 0; m < 4; ++m) {
    if (m >= st.len) break;
    lo = min(lo, v[m]);
    hi = max(hi, v[m]);
    ln += st.w[m] * log(max(v[m], vec3(1e-30)));
  }
  vec3 lagrange = st.t < 0.0 ? exp(ln) : clamp(exp(ln), lo, hi);
  return mix(GeoMix(a, b, st.t), lagrange, vec3(greaterThan(lo, vec3(0.0))));
}

// Continuous sun node coordinate of an elevation above the observer's horizon (degrees).
float SkyViewSunCoord(float above_horizon_deg) {
  float first = 0.0;
  for (int s = 0; s < SV_N_SUN_SEGMENTS; ++s) {
    vec3 seg = skyview_sun_segments[s];
    if (above_horizon_deg <= seg.x + seg.z * seg.y) {
      return first + max((above_horizon_deg - seg.x) / seg.y, 0.0);
    }
    first += seg.z;
  }
  return float(SV_N_SUN - 1);
}

// sin, cos, acos and asinh to 32-bit precision. GLSL ES leaves their precision to the device:
// SwiftShader's (headless Chromium) are within 1.9e-4 (sin, cos) and 6.7e-5 (acos) absolute,
// 1000 times its asin's and atan's, and its asinh errs by 5e-5 at -18 (log(x + sqrt(x^2 + 1))
// cancels for x < 0); the limb rows' coordinate (ln L changes 27 per unit of it in twilight
// aloft), the sky rows' focus (asinh of up to 24 times the coordinate), the sun coordinate
// (gamma cos(phi)) and the azimuth column need them to 1e-6. sin and cos: the argument reduced
// by multiples of pi/2 (pi/2 in two parts, Cody & Waite 1980), then the Taylor polynomials to
// x^9 and x^10 (|x| <= pi/4: within 3e-8).
vec2 SkyViewSinCos(float x) {
  float n = floor(x * 0.63661977 + 0.5);
  float r = (x - n * 1.5707963705062866) + n * 4.371139000186243e-8;
  float r2 = r * r;
  float s = r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 +
      r2 * (1.0 / 362880.0)))));
  float c = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40320.0 +
      r2 * (-1.0 / 3628800.0)))));
  int q = int(n - 4.0 * floor(n * 0.25));
  return q == 0 ? vec2(s, c) : q == 1 ? vec2(c, -s) : q == 2 ? vec2(-s, -c) : vec2(-c, s);
}
float SkyViewSin(float x) { return SkyViewSinCos(x).x; }
float SkyViewCos(float x) { return SkyViewSinCos(x).y; }
// acos from atan (accurate), sqrt((1 - x)(1 + x)) without cancellation near |x| = 1.
float SkyViewAcos(float x) {
  x = clamp(x, -1.0, 1.0);
  return atan(sqrt(max((1.0 - x) * (1.0 + x), 0.0)), x);
}
// asinh, odd: of |x| (no cancellation); below 1/8 its series to x^7 (log(1 + a) would lose a's
// digits).
float SkyViewAsinh(float x) {
  float a = abs(x);
  if (a < 0.125) {
    float x2 = x * x;
    return x * (1.0 + x2 * (-1.0 / 6.0 + x2 * (3.0 / 40.0 + x2 * (-5.0 / 112.0))));
  }
  return sign(x) * log(a + sqrt(a * a + 1.0));
}

// The limb rows' coordinate x (0 at the horizontal, 1 at the horizon) of the ray's depth
// y = (r - r_t) / h: the root in [0, 1] of 2x^2 - x^3 = y (the reader's limb_row).
float SkyViewLimbRow(float y) {
  float phi = SkyViewAcos(1.0 - 27.0 / 16.0 * clamp(y, 0.0, 1.0));
  return clamp(2.0 / 3.0 + 4.0 / 3.0 * SkyViewCos(phi / 3.0 - 2.0 * PI / 3.0), 0.0, 1.0);
}

// The limb rows' focus on the band above the earth's shadow seen from altitude (the reader's
// limb_row_focus) at sun coordinate sun_deg and altitude h: xc = SkyViewLimbRow of the band's
// depth (depth.x + depth.y s + depth.z s^2) / h, k = SV_LIMB_BAND_FOCUS times the fades.
// The band focus's fade (the reader's limb_band_fade): the slices' depth map and the limb's sun
// stencil act with it.
float SkyViewLimbBandFade(float sun_deg, float h) {
  if (h <= 0.0) return 0.0;
  return smoothstep(SV_LIMB_BAND_SUN_RANGE.x, SV_LIMB_BAND_SUN_RANGE.y, sun_deg) *
      (1.0 - smoothstep(SV_LIMB_BAND_SUN_RANGE.z, SV_LIMB_BAND_SUN_RANGE.w, sun_deg)) *
      smoothstep(SV_LIMB_BAND_ALTITUDE.x, SV_LIMB_BAND_ALTITUDE.y, h) *
      (1.0 - smoothstep(SV_LIMB_BAND_ALTITUDE.z, SV_LIMB_BAND_ALTITUDE.w, h));
}

// Where the band's focus is off, the focus on the earth's shadow's edge seen from 35-45 km (the
// reader's limb_edge_focus): depth SV_LIMB_EDGE_DEPTH.x + SV_LIMB_EDGE_DEPTH.y s, strength
// SV_LIMB_EDGE_FOCUS times the smoothsteps of SV_LIMB_EDGE_SUN_RANGE and SV_LIMB_EDGE_ALTITUDE.
vec2 SkyViewLimbFocus(float sun_deg, float h) {
  float f = SkyViewLimbBandFade(sun_deg, h);
  if (f <= 0.0 || h <= 0.0) {
    float g = smoothstep(SV_LIMB_EDGE_SUN_RANGE.x, SV_LIMB_EDGE_SUN_RANGE.y, sun_deg) *
        (1.0 - smoothstep(SV_LIMB_EDGE_SUN_RANGE.z, SV_LIMB_EDGE_SUN_RANGE.w, sun_deg)) *
        smoothstep(SV_LIMB_EDGE_ALTITUDE.x, SV_LIMB_EDGE_ALTITUDE.y, h) *
        (1.0 - smoothstep(SV_LIMB_EDGE_ALTITUDE.z, SV_LIMB_EDGE_ALTITUDE.w, h));
    if (g <= 0.0 || h <= 0.0) return vec2(0.0);
    float edge = SV_LIMB_EDGE_DEPTH.x + SV_LIMB_EDGE_DEPTH.y * sun_deg;
    return vec2(SkyViewLimbRow(clamp(edge / h, 0.0, 1.0)), g * SV_LIMB_EDGE_FOCUS);
  }
  float depth = SV_LIMB_BAND_DEPTH.x + SV_LIMB_BAND_DEPTH.y * sun_deg +
      SV_LIMB_BAND_DEPTH.z * sun_deg * sun_deg;
  return vec2(SkyViewLimbRow(clamp(depth / h, 0.0, 1.0)), f * SV_LIMB_BAND_FOCUS);
}

// The near end's share n of a limb ray's weight aloft away from the sun (the reader's
// limb_near_end), at altitude h (m), its tangent point depth (m) below it, cos_phi the cosine of
// its azimuth from the sun.
float SkyViewLimbNearEnd(float cos_phi, float h, float depth) {
  return (1.0 - smoothstep(SV_LIMB_NEAR_END_AZIMUTH.x, SV_LIMB_NEAR_END_AZIMUTH.y, cos_phi)) *
      smoothstep(SV_LIMB_NEAR_END_DEPTH.x, SV_LIMB_NEAR_END_DEPTH.y, depth) *
      smoothstep(SV_LIMB_NEAR_END_ALTITUDE.x, SV_LIMB_NEAR_END_ALTITUDE.y, h);
}

// The tangent point's weight of a limb ray at altitude h (m) whose tangent point lies depth (m)
// below it, cos_phi the cosine of its azimuth from the sun (the reader's limb_tangent_weight):
// (1 - exp(-depth / SV_LIMB_SHADOW_SCALE)) (1 - n).
float SkyViewLimbTangentWeight(float cos_phi, float h, float depth) {
  return (1.0 - exp(-depth / SV_LIMB_SHADOW_SCALE)) * (1.0 - SkyViewLimbNearEnd(cos_phi, h, depth));
}

// The tangent point's weight at which altitude node h_n (m) is read on the limb by a query at
// altitude h whose tangent point lies depth (m) below it, y_limb = depth / h (the reader's
// limb_node_shift): (e_q + b (e_n - e_q)) (1 - n(h_n, y_limb h_n)), e the exponential of the
// query's depth and of the node's y_limb h_n, b the smoothstep of h over
// SV_LIMB_NODE_WEIGHT_ALTITUDE (the node's whole weight aloft, the query's exponential below).
float SkyViewLimbNodeWeight(float cos_phi, float h, float depth, float h_n, float y_limb) {
  float b = smoothstep(SV_LIMB_NODE_WEIGHT_ALTITUDE.x, SV_LIMB_NODE_WEIGHT_ALTITUDE.y, h);
  float e_q = 1.0 - exp(-depth / SV_LIMB_SHADOW_SCALE);
  float e_n = 1.0 - exp(-y_limb * h_n / SV_LIMB_SHADOW_SCALE);
  return (e_q + b * (e_n - e_q)) * (1.0 - SkyViewLimbNearEnd(cos_phi, h_n, y_limb * h_n));
}

// The sun coordinate's shift at which altitude node h_n (m) is read for a limb query at altitude
// h (the reader's limb_node_shift): the node's ray at the query's depth fraction y_limb read
// w_n t_n + omega (t - t_n) above the observer's horizon, t = gamma cos_phi + dip_t - dip the
// query's tangent point's horizon relative to its own (t_n the node's ray's), w_n the node's
// weight (SkyViewLimbNodeWeight); omega = w_n, moved to the query's weight w over
// SV_LIMB_NODE_QUERY_WEIGHT (smoothstep in h).
float SkyViewLimbNodeShift(float h, float h_n, float y_limb, float cos_phi, float gamma,
                           float dip, float dip_t, float h_t) {
  float w_n = SkyViewLimbNodeWeight(cos_phi, h, h - h_t, h_n, y_limb);
  float t = gamma * cos_phi + dip_t - dip;
  float lambda = smoothstep(SV_LIMB_NODE_QUERY_WEIGHT.x, SV_LIMB_NODE_QUERY_WEIGHT.y, h);
  if (lambda <= 0.0) return dip + w_n * t;
  // The node's ray: 1 - cos(gamma_n) = y_limb h_n / r_n.
  float depth_n = y_limb * h_n;
  float gamma_n = 2.0 * asin(min(sqrt(0.5 * depth_n / (bottom_radius + h_n)), 1.0));
  float h_tn = max(h_n - depth_n, 0.0);
  float dip_n = atan(sqrt(h_n * (2.0 * bottom_radius + h_n)), bottom_radius);
  float dip_tn = atan(sqrt(h_tn * (2.0 * bottom_radius + h_tn)), bottom_radius);
  float t_n = gamma_n * cos_phi + dip_tn - dip_n;
  float w = SkyViewLimbTangentWeight(cos_phi, h, h - h_t);
  float omega = w_n + lambda * (w - w_n);
  return dip + w_n * t_n + omega * (t - t_n);
}

// The band's depth (m) on the limb at sun coordinate sun_deg, at least SV_LIMB_BAND_DEPTH_FLOOR
// (the reader's limb_band_depth_m).
float SkyViewLimbBandDepth(float sun_deg) {
  float s = clamp(sun_deg, SV_LIMB_BAND_SUN_RANGE.x - 1.0, SV_LIMB_BAND_SUN_RANGE.w);
  return max(SV_LIMB_BAND_DEPTH.x + SV_LIMB_BAND_DEPTH.y * s + SV_LIMB_BAND_DEPTH.z * s * s,
             SV_LIMB_BAND_DEPTH_FLOOR);
}

// The depth at which the limb rows of the slice of sun coordinate s_n and altitude h_n are read
// for a query at depth y with sun coordinate s_q at altitude h_q (the reader's
// limb_slice_depth): two pieces, the horizontal and the horizon fixed, the band's depth fraction
// yb = min(D(s_q) / h_q, SV_LIMB_BAND_MAX_FRACTION) moved to ybn = min(yb rho,
// SV_LIMB_BAND_MAX_FRACTION), rho = (h_q / h_n)^SV_LIMB_BAND_ALTITUDE_EXPONENT D(s_n) / D(s_q),
// the second piece faded to y rho by 1 - smoothstep(SV_LIMB_BAND_HORIZON_HELD, yb) (the reader's
// limb_slice_map); faded with the query's focus.
float SkyViewLimbSliceMap(float y, float s_q, float h_q, float s_n, float h_n) {
  float dq = SkyViewLimbBandDepth(s_q);
  float rho = pow(h_q / h_n, SV_LIMB_BAND_ALTITUDE_EXPONENT) * SkyViewLimbBandDepth(s_n) / dq;
  float yb = min(dq / h_q, SV_LIMB_BAND_MAX_FRACTION);
  float ybn = min(yb * rho, SV_LIMB_BAND_MAX_FRACTION);
  float w = 1.0 - smoothstep(SV_LIMB_BAND_HORIZON_HELD.x, SV_LIMB_BAND_HORIZON_HELD.y, yb);
  return y <= yb ? y * rho
                 : y * rho + w * (ybn + (y - yb) * (1.0 - ybn) / (1.0 - yb) - y * rho);
}

float SkyViewLimbSliceDepth(float y, float s_q, float h_q, float s_n, float h_n) {
  float f = SkyViewLimbBandFade(s_q, h_q);
  if (f <= 0.0 || h_n <= 0.0) return y;
  return y + f * (clamp(SkyViewLimbSliceMap(y, s_q, h_q, s_n, h_n), 0.0, 1.0) - y);
}

// The sun node coordinate (degrees) of the sun coordinate s (degrees) at warp strength b and
// centre c (degrees): the inverse of the twilight warp s = c + e sinh(b (t - c) / e) / sinh(b),
// e = c - SV_SUN_WARP_LO below c, SV_SUN_WARP_HI - c above (the reader's sun_unwarp).
float SkyViewSunUnwarp(float s, float b, float c) {
  if (b < 1e-6 || s <= SV_SUN_WARP_LO || s >= SV_SUN_WARP_HI) return s;
  float e = s < c ? c - SV_SUN_WARP_LO : SV_SUN_WARP_HI - c;
  return c + e * SkyViewAsinh((s - c) * sinh(b) / e) / b;
}

// The twilight warp's centre (degrees) of a query at altitude h in view segment `segment`, its
// azimuth's cosine cos_phi from the sun (the reader's sun_warp_centre): on the sky rows towards
// the sun SV_SUN_WARP_CENTRE max(cos_phi, 0)^2 smoothstep(SV_SUN_WARP_CENTRE_ALTITUDE, h)
// (dip(r) - dip(top)), where the sunlight grazing the ground starts to reach the top above the
// observer; 0 elsewhere. The dips from rho, atan(rho, bottom_radius).
// The azimuth weight of the sky rows' exit shift (the reader's sky_exit_azimuth): cos_phi
// towards the sun, cos_phi (1 + cos_phi / f)^2 down to -f away from it, 0 beyond.
float SkyViewExitAzimuth(float cos_phi) {
  float f = SV_SKY_EXIT_AZIMUTH_FADE;
  if (cos_phi >= 0.0) return cos_phi;
  if (cos_phi > -f) return cos_phi * (1.0 + cos_phi / f) * (1.0 + cos_phi / f);
  return 0.0;
}

float SkyViewSunWarpCentre(float h, int segment, float cos_phi) {
  float w = smoothstep(SV_SUN_WARP_CENTRE_ALTITUDE.x, SV_SUN_WARP_CENTRE_ALTITUDE.y, h);
  if (segment != 0 || cos_phi <= 0.0 || w <= 0.0) return 0.0;
  float top = top_radius - bottom_radius;
  float dip = atan(sqrt(h * (2.0 * bottom_radius + h)), bottom_radius);
  float dip_top = atan(sqrt(top * (2.0 * bottom_radius + top)), bottom_radius);
  return SV_SUN_WARP_CENTRE * cos_phi * cos_phi * w * degrees(dip - dip_top);
}

// The altitude nodes (m) and their base abscissas (the altitude axis's Lagrange abscissas: the
// integers of the base map and the halves inserted between some of them).
const float sv_alt_nodes[SV_N_ALT] = SV_ALT_NODES;
const float sv_alt_x[SV_N_ALT] = SV_ALT_X;

// The altitude axis's stencil at node coordinate y (SkyViewAltitudeSun's k0 + tk): the
// Lagrange weights at the query's base abscissa over the nodes' (the reader's altitude stencil).
SvStencil SkyViewAltitudeStencil(float y) {
  SvStencil st = SkyViewStencil(y, 0, SV_N_ALT - 1, false, 0.0);
  if (st.t == 0.0) return st;
  float xq = mix(sv_alt_x[st.i0], sv_alt_x[st.i0 + 1], st.t);
  float x[4];
  for (int m = 0; m < 4; ++m) x[m] = sv_alt_x[min(st.first + m, SV_N_ALT - 1)];
  st.w = SkyViewLagrange(xq, x, st.len);
  return st;
}

// The row coordinate of the unfocused coordinate x0 on rows focused with strength k at xc (the
// reader's focus_coord): (asinh(k (x0 - xc)) - A) / (B - A), A = asinh(-k xc),
// B = asinh(k (1 - xc)); x0 where k = 0.
float SkyViewFocusCoord(float x0, float xc, float k) {
  if (k < 1e-6) return x0;
  float a = SkyViewAsinh(-k * xc);
  float b = SkyViewAsinh(k * (1.0 - xc));
  return clamp((SkyViewAsinh(k * (x0 - xc)) - a) / (b - a), 0.0, 1.0);
}

// The sun coordinate s (degrees) of the sun node coordinate t (degrees) at warp strength b,
// centred at 0 (the reader's sun_warp with c = 0: the band and limb maps' slices, below 25 km,
// where the centre is 0): s = e sinh(b t / e) / sinh(b).
float SkyViewSunWarp(float t, float b) {
  if (b < 1e-6 || t <= SV_SUN_WARP_LO || t >= SV_SUN_WARP_HI) return t;
  float e = t < 0.0 ? -SV_SUN_WARP_LO : SV_SUN_WARP_HI;
  return e * sinh(b * t / e) / sinh(b);
}

// The sun axis's warp strength at altitude h (m) (the reader's warp_strength): b = SV_SUN_WARP
// sqrt(h / thickness), h clamped to the atmosphere.
float SkyViewWarpStrength(float h) {
  return SV_SUN_WARP * sqrt(clamp(h / (top_radius - bottom_radius), 0.0, 1.0));
}

// The lowest sun node the limb rows of the altitude node h_n read for a query at depth y with
// sun coordinate s_q at altitude h_q, whose sun stencil is ss (the reader's limb_sun_lowest):
// from ss.first up to ss.i0, the first whose slice (its node warped at h_n) is not read past its
// horizon, y + f (SkyViewLimbSliceMap - y) > 1, f the query's focus fade.
int SkyViewLimbSunLowest(float y, float s_q, float h_q, float h_n, SvStencil ss) {
  float f = SkyViewLimbBandFade(s_q, h_q);
  if (f <= 0.0 || h_n <= 0.0) return ss.first;
  float b_n = SkyViewWarpStrength(h_n);
  int lo = ss.first;
  for (int j = ss.first; j < ss.i0; ++j) {
    float s_n = SkyViewSunWarp(SkyViewSunNodeDeg(j), b_n);
    if (y + f * (SkyViewLimbSliceMap(y, s_q, h_q, s_n, h_n) - y) > 1.0) lo = j + 1;
  }
  return lo;
}

// Altitude node h_n's sun stencil on the limb rows (the reader's limb_sun_stencil): where the
// sun interval's lower node's slice would be read deeper than SV_LIMB_BAND_DEEPEST, the line
// through the two nodes above it, extrapolated to above_deg (t < 0, not bounded: SkyViewMix);
// else without the lower nodes read past the horizon (SkyViewLimbSunLowest).
SvStencil SkyViewLimbSunStencil(SvStencil ss, float y, float s_q, float h_q, float h_n,
                                float above_deg) {
  if (ss.len <= 2) return ss;
  float f = SkyViewLimbBandFade(s_q, h_q);
  if (f > 0.0 && h_n > 0.0 && ss.t > 0.0 && ss.i0 + 2 < SV_N_SUN) {
    float b_n = SkyViewWarpStrength(h_n);
    float s_n = SkyViewSunWarp(SkyViewSunNodeDeg(ss.i0), b_n);
    if (y + f * (SkyViewLimbSliceMap(y, s_q, h_q, s_n, h_n) - y) > SV_LIMB_BAND_DEEPEST) {
      SvStencil st;
      st.first = ss.i0 + 1;
      st.i0 = st.first;
      st.len = 2;
      float x0 = SkyViewSunNodeDeg(st.first);
      st.t = min((above_deg - x0) / (SkyViewSunNodeDeg(st.first + 1) - x0), 0.0);
      st.w = vec4(1.0 - st.t, st.t, 0.0, 0.0);
      return st;
    }
  }
  if (ss.i0 == ss.first) return ss;
  int lowest = SkyViewLimbSunLowest(y, s_q, h_q, h_n, ss);
  if (lowest == ss.first) return ss;
  return SkyViewStencil(float(ss.i0) + ss.t, lowest, SV_N_SUN - 1, true, above_deg);
}

// The sky rows' full focus strength at altitude h (the reader's band_focus_strength): grows
// by SV_BAND_GROWTH between SV_BAND_GROWTH_ALTITUDE, and by SV_BAND_FOCUS_ALOFT between
// SV_BAND_FOCUS_ALOFT_ALTITUDE.
float SkyViewBandStrength(float h) {
  return SV_BAND_FOCUS *
      (1.0 + SV_BAND_GROWTH * smoothstep(SV_BAND_GROWTH_ALTITUDE.x, SV_BAND_GROWTH_ALTITUDE.y, h)) *
      (1.0 + SV_BAND_FOCUS_ALOFT *
                 smoothstep(SV_BAND_FOCUS_ALOFT_ALTITUDE.x, SV_BAND_FOCUS_ALOFT_ALTITUDE.y, h));
}

// The share of the sky rows' focus that moves and grows aloft at the band's elevation c and
// altitude h (the reader's sky_row_focus): under a low band (1 - smoothstep over
// SV_BAND_CENTRE_RANGE of c) from SV_BAND_FOCUS_PLACE_ALTITUDE up.
float SkyViewFocusAloft(float c, float h) {
  return smoothstep(SV_BAND_FOCUS_PLACE_ALTITUDE.x, SV_BAND_FOCUS_PLACE_ALTITUDE.y, h) *
      (1.0 - smoothstep(SV_BAND_CENTRE_RANGE.x, SV_BAND_CENTRE_RANGE.y, c));
}

// The share (0..1) of the sky rows' focus's width at the band's elevation c and altitude h (the
// reader's sky_row_focus): under a low band (1 - smoothstep over SV_BAND_CENTRE_RANGE of c) in
// from SV_BAND_FOCUS_WIDTH_ALTITUDE.xy, out from .zw.
float SkyViewFocusWide(float c, float h) {
  return smoothstep(SV_BAND_FOCUS_WIDTH_ALTITUDE.x, SV_BAND_FOCUS_WIDTH_ALTITUDE.y, h) *
      (1.0 - smoothstep(SV_BAND_FOCUS_WIDTH_ALTITUDE.z, SV_BAND_FOCUS_WIDTH_ALTITUDE.w, h)) *
      (1.0 - smoothstep(SV_BAND_CENTRE_RANGE.x, SV_BAND_CENTRE_RANGE.y, c));
}

// The sky rows' focus's elevation over the band's c at altitude h (the reader's sky_row_focus):
// SV_BAND_FOCUS_PLACE_ALOFT of the band opposite the sun (c SV_BAND_ANTISOLAR) aloft under a low
// band (and where the focus is wide, SkyViewFocusWide), 1 elsewhere.
float SkyViewFocusPlace(float c, float h) {
  float aloft = SV_BAND_FOCUS_PLACE_ALOFT * SV_BAND_ANTISOLAR;
  float place = 1.0 + (aloft - 1.0) * SkyViewFocusAloft(c, h);
  return place + (aloft - place) * SkyViewFocusWide(c, h);
}

// The weight (0..1) of the maps relative to the band (SkyViewBandSlice, SkyViewBandRelative) at
// the sun coordinate sun_deg and altitude h (the reader's band_map_weight): the focus's fades in
// the sun and the altitude, without its fade in the band's elevation.
float SkyViewBandWeight(float sun_deg, float h) {
  return smoothstep(SV_BAND_SUN_RANGE.x, SV_BAND_SUN_RANGE.y, sun_deg) *
      (1.0 - smoothstep(SV_BAND_SUN_RANGE.z, SV_BAND_SUN_RANGE.w, sun_deg)) *
      (1.0 - smoothstep(SV_BAND_ALTITUDE.x, SV_BAND_ALTITUDE.y, h));
}

// The band's further growth above SV_BAND_CENTRE_ALOFT_ALTITUDE.y (the reader's band_centre_top):
// rate per km up to SV_BAND_CENTRE_TOP.x (rate SV_BAND_CENTRE_TOP.y, in the slices' map
// SV_BAND_SLICE_TOP).
float SkyViewBandCentreTop(float h, float rate) {
  return rate *
      clamp(h - SV_BAND_CENTRE_ALOFT_ALTITUDE.y, 0.0,
            max(SV_BAND_CENTRE_TOP.x - SV_BAND_CENTRE_ALOFT_ALTITUDE.y, 0.0)) / 1000.0;
}

// The band's elevation (degrees) opposite the sun with the sun sun_deg above the observer's
// horizon at altitude h (the reader's band_centre_deg).
float SkyViewBandCentre(float sun_deg, float h) {
  // u = SV_BAND_SUN - sun_deg turned smoothly to 0 over SV_BAND_SUN_SOFT: w ln(1 + e^x).
  float x = (SV_BAND_SUN - sun_deg) / SV_BAND_SUN_SOFT;
  float u = SV_BAND_SUN_SOFT * (max(x, 0.0) + log(1.0 + exp(-abs(x))));
  // The low fit up to SV_BAND_CENTRE_ALOFT_ALTITUDE.x, scaled by 1 + SV_BAND_CENTRE_ALOFT per km
  // above it up to SV_BAND_CENTRE_ALOFT_ALTITUDE.y, + SV_BAND_CENTRE_TOP.y per km above that up to
  // SV_BAND_CENTRE_TOP.x.
  float km = clamp(h, 0.0, SV_BAND_CENTRE_ALOFT_ALTITUDE.x) / 1000.0;
  float aloft = 1.0 + SV_BAND_CENTRE_ALOFT *
      clamp(h - SV_BAND_CENTRE_ALOFT_ALTITUDE.x, 0.0,
            SV_BAND_CENTRE_ALOFT_ALTITUDE.y - SV_BAND_CENTRE_ALOFT_ALTITUDE.x) / 1000.0 +
      SkyViewBandCentreTop(h, SV_BAND_CENTRE_TOP.y);
  return min(((SV_BAND_CENTRE.x + SV_BAND_CENTRE.y * km) * u +
              (SV_BAND_CENTRE.z + SV_BAND_CENTRE.w * km) * u * u) * aloft, 45.0);
}

// The sky rows' focus on the band above the earth's shadow (the reader's sky_row_focus): the
// band's elevation c (degrees, SkyViewBandCentre) and the focus strength k (per degree) with the
// sun sun_deg above the observer's horizon at altitude h (faded out as c rises through
// SV_BAND_CENTRE_RANGE).
void SkyViewBandFocus(float sun_deg, float h, out float c, out float k) {
  c = SkyViewBandCentre(sun_deg, h);
  float low = 1.0 - smoothstep(SV_BAND_CENTRE_RANGE.x, SV_BAND_CENTRE_RANGE.y, c);
  float f = SkyViewBandWeight(sun_deg, h) *
      (low * (1.0 + SV_BAND_FOCUS_HIGH * SkyViewFocusAloft(c, h)) +
       SV_BAND_CENTRE_FLOOR * (1.0 - low));
  k = f * SkyViewBandStrength(h) * (1.0 + SV_BAND_FOCUS_WIDE * SkyViewFocusWide(c, h));
}

// The band's depth delta (degrees below the horizontal) at altitude h (the reader's
// band_depth_deg): SV_BAND_DEPTH per km up to SV_BAND_DEPTH_TOP.
float SkyViewBandDepth(float h) {
  return SV_BAND_DEPTH * clamp(h, 0.0, SV_BAND_DEPTH_TOP) / 1000.0;
}

// The band's depth (degrees) in the columns' map at altitude h (the reader's
// band_azimuth_depth_deg): SkyViewBandDepth moved to SV_BAND_AZIMUTH_DEPTH_ALOFT between
// SV_BAND_AZIMUTH_DEPTH_ALTITUDE.
float SkyViewBandAzimuthDepth(float h) {
  float d = SkyViewBandDepth(h);
  return d + (SV_BAND_AZIMUTH_DEPTH_ALOFT - d) *
      smoothstep(SV_BAND_AZIMUTH_DEPTH_ALTITUDE.x, SV_BAND_AZIMUTH_DEPTH_ALTITUDE.y, h);
}

// tanh from exp (odd: of |x|).
float SkyViewTanh(float x) {
  float e = exp(-2.0 * abs(x));
  return sign(x) * (1.0 - e) / (1.0 + e);
}

// The columns' focus aloft at azimuth phi (rad) and altitude h (the reader's azimuth_focus):
// (beta, G(phi)), beta = SV_AZ_FOCUS.x smoothstep(SV_AZ_FOCUS_ALTITUDE, h), G(phi) =
// (tanh((phi - c) / w) - tanh(-c / w)) / (tanh((pi - c) / w) - tanh(-c / w)), (c, w) =
// SV_AZ_FOCUS.yz (degrees).
vec2 SkyViewAzimuthFocus(float phi, float h) {
  float beta = SV_AZ_FOCUS.x * smoothstep(SV_AZ_FOCUS_ALTITUDE.x, SV_AZ_FOCUS_ALTITUDE.y, h);
  if (beta <= 0.0) return vec2(0.0);
  float c = radians(SV_AZ_FOCUS.y);
  float w = radians(SV_AZ_FOCUS.z);
  float g0 = SkyViewTanh(-c / w);
  return vec2(beta, (SkyViewTanh((phi - c) / w) - g0) / (SkyViewTanh((PI - c) / w) - g0));
}

// The weight of the columns' square-root map at altitude h (the reader's azimuth_weight): from
// SV_AZ_GROUND_WEIGHT below SV_AZ_ALTITUDE.x to SV_AZ_WEIGHT above SV_AZ_ALTITUDE.y.
float SkyViewAzimuthWeight(float h) {
  return SV_AZ_GROUND_WEIGHT -
      (SV_AZ_GROUND_WEIGHT - SV_AZ_WEIGHT) * smoothstep(SV_AZ_ALTITUDE.x, SV_AZ_ALTITUDE.y, h);
}

// The column coordinate of azimuth phi (rad) at altitude h (the reader's azimuth_coord):
// (alpha sqrt(phi / pi) + (1 - alpha - beta) sin^2(phi / 2) + beta G(phi)) (N_AZ - 1), alpha
// = SkyViewAzimuthWeight (the columns denser around 90 degrees from the sun aloft),
// (beta, G) = SkyViewAzimuthFocus (0 below SV_AZ_FOCUS_ALTITUDE.x).
float SkyViewAzimuthColumn(float phi, float h) {
  float alpha = SkyViewAzimuthWeight(h);
  vec2 focus = SkyViewAzimuthFocus(phi, h);
  float half_sin = SkyViewSin(0.5 * phi);
  return (alpha * sqrt(clamp(phi / PI, 0.0, 1.0)) +
          (1.0 - alpha - focus.x) * half_sin * half_sin + focus.x * focus.y) *
      float(SV_N_AZ - 1);
}

// The azimuth (rad) from the sun of column a at altitude h below SV_AZ_FOCUS_ALTITUDE.x (the
// reader's azimuth_node): the root x of alpha x + (1 - alpha) sin^2(pi x^2 / 2) = a / (N_AZ - 1),
// phi = pi x^2, by Newton's method from x = a / (N_AZ - 1) (the root where alpha = 1; 6 steps).
float SkyViewAzimuthNode(int a, float h) {
  float target = float(a) / float(SV_N_AZ - 1);
  float alpha = SkyViewAzimuthWeight(h);
  float x = target;
  if (alpha < 1.0 && a > 0 && a < SV_N_AZ - 1) {
    for (int i = 0; i < 6; ++i) {
      float s = SkyViewSin(0.5 * PI * x * x);
      float f = alpha * x + (1.0 - alpha) * s * s - target;
      x = clamp(x - f / (alpha + (1.0 - alpha) * PI * x * SkyViewSin(PI * x * x)), 0.0, 1.0);
    }
  }
  return PI * x * x;
}

// The cosines of the columns' azimuths from the sun at each altitude node (the reader's
// azimuth_node at the node's altitude): column a of altitude node k at k * SV_N_AZ + a.
const float sv_az_node_cos[SV_N_ALT * SV_N_AZ] = SV_AZ_NODE_COS;

// The focused coordinate G(x0) of a focus of strength k over [xc, xc + w] (the reader's
// focus_warp): asinh(k (x0 - xc)) below xc, k (x0 - xc) across the focus, k w + asinh(k (x0 - xc -
// w)) past it.
float SkyViewFocusWarp(float x0, float xc, float k, float w) {
  if (x0 < xc) return SkyViewAsinh(k * (x0 - xc));
  if (x0 <= xc + w) return k * (x0 - xc);
  return k * w + SkyViewAsinh(k * (x0 - xc - w));
}

// The sky rows' coordinate x (0 at the zenith, 1 at the horizontal) of the elevation
// elevation_deg with focus (c, k) (the reader's sky_row): x0 = 1 - sqrt(elevation / 90) (version
// 3's coordinate, x where k = 0), x = (asinh(k (x0 - x_c)) - A) / (B - A), x_c = 1 - sqrt(c / 90),
// A = asinh(-k x_c), B = asinh(k (1 - x_c)).
float SkyViewSkyRow(float elevation_deg, float c, float k, float w) {
  float x0 = 1.0 - sqrt(clamp(elevation_deg / 90.0, 0.0, 1.0));
  if (k < 1e-6) return x0;
  float xc = 1.0 - sqrt(clamp(c / 90.0, 0.0, 1.0));
  float a = SkyViewFocusWarp(0.0, xc, k, w);
  float b = SkyViewFocusWarp(1.0, xc, k, w);
  return clamp((SkyViewFocusWarp(x0, xc, k, w) - a) / (b - a), 0.0, 1.0);
}

// The sky rows' focus's width (in x0) at the band's elevation c and altitude h (the reader's
// sky_row_focus): from the focus's elevation c SkyViewFocusPlace(c, h) down to the band's
// elevation (c SV_BAND_ANTISOLAR + delta) SV_BAND_FOCUS_WIDTH_AZIMUTH - delta (at least
// SV_BAND_FOCUS_WIDTH_FLOOR), delta = SkyViewBandAzimuthDepth(h), times SkyViewFocusWide(c, h).
float SkyViewFocusWidth(float c, float h) {
  float wide = SkyViewFocusWide(c, h);
  if (wide <= 0.0) return 0.0;
  float delta = SkyViewBandAzimuthDepth(h);
  float e_lo = max((c * SV_BAND_ANTISOLAR + delta) * SV_BAND_FOCUS_WIDTH_AZIMUTH - delta,
                   SV_BAND_FOCUS_WIDTH_FLOOR);
  float x_lo = 1.0 - sqrt(clamp(e_lo / 90.0, 0.0, 1.0));
  float x_hi = 1.0 - sqrt(clamp(c * SkyViewFocusPlace(c, h) / 90.0, 0.0, 1.0));
  return max(x_lo - x_hi, 0.0) * wide;
}

// The elevation (degrees) at the column azimuth cos_phi_a (cosine) that lies where
// elevation_deg lies at the query's azimuth cos_phi_q relative to the band above the earth's
// shadow (the reader's band_relative_elevation): the band's elevation scales as -cos(phi) about
// SkyViewBandAzimuthDepth(h) below the horizontal; faded out above 2-4 times the band's height, below
// SV_BAND_HORIZON (to the horizontal), with the band's elevation c of SkyViewBandFocus and the
// maps' weight of SkyViewBandWeight, and within SV_BAND_ANTISOLAR_RANGE of -cos(phi) (the
// identity within 102 deg of the sun).
float SkyViewBandRelative(float elevation_deg, float c, float weight, float h, float cos_phi_q,
                          float cos_phi_a) {
  float delta = SkyViewBandAzimuthDepth(h);
  float w = max(c * SV_BAND_ANTISOLAR + delta, 0.5);
  float ratio = max(-cos_phi_a, SV_BAND_ANTISOLAR_RANGE.x) /
      max(-cos_phi_q, SV_BAND_ANTISOLAR_RANGE.x);
  float fade = weight * (1.0 - smoothstep(2.0 * w, 4.0 * w, elevation_deg)) *
      smoothstep(SV_BAND_ANTISOLAR_RANGE.x, SV_BAND_ANTISOLAR_RANGE.y, -cos_phi_q);
  // From -delta up, through the horizontal into the limb rows (the reader's band_horizon_taper;
  // the displacement vanishes at -delta).
  float taper = elevation_deg >= -delta ? 1.0 : 0.0;
  return elevation_deg + taper * fade * (elevation_deg + delta) * (ratio - 1.0);
}

// The row stencil of elevation_deg (degrees) for an observer at altitude h on the slice's rows
// of band elevation c and focus k (the reader's band_row; the focus at c SkyViewFocusPlace at
// the slice's altitude limb.z): the sky rows above the horizontal, below it the limb rows at
// the observer's altitude (the tangent point's depth 2 r sin^2(e/2) / h) on the slice's limb
// rows, limb = (the query's sun coordinate, the slice's, the slice's altitude)
// (SkyViewLimbSliceDepth, SkyViewLimbFocus).
SvStencil SkyViewBandRowStencil(float elevation_deg, float h, float c, float k, vec3 limb) {
  if (elevation_deg >= 0.0 || h <= 0.0) {
    float x = SkyViewSkyRow(elevation_deg, c * SkyViewFocusPlace(c, limb.z), k,
                            SkyViewFocusWidth(c, limb.z));
    return SkyViewStencil(x * float(SV_N_VIEW_SKY - 1), 0, SV_N_VIEW_SKY - 1, false, 0.0);
  }
  float s = SkyViewSin(0.5 * radians(elevation_deg));
  float y = clamp(2.0 * (bottom_radius + h) * s * s / h, 0.0, 1.0);
  vec2 focus = SkyViewLimbFocus(limb.y, limb.z);
  float y_n = SkyViewLimbSliceDepth(y, limb.x, h, limb.y, limb.z);
  return SkyViewStencil(float(SV_N_VIEW_SKY) +
                            SkyViewFocusCoord(SkyViewLimbRow(y_n), focus.x, focus.y) *
                                float(SV_N_VIEW_LIMB - 1),
                        SV_N_VIEW_SKY, SV_N_VIEW_UP - 1, false, 0.0);
}

// The band's elevation (degrees, over SV_BAND_ANTISOLAR) in the slices' map at the sun
// coordinate sun_deg and altitude h (the reader's band_slice_centre_deg): SkyViewBandCentre's low
// fit at min(h, SV_BAND_CENTRE_ALOFT_ALTITUDE.x) times 1 + a x + (b - a) x^2 / (2 L), x the km
// above SV_BAND_CENTRE_ALOFT_ALTITUDE.x up to L, its span, (a, b) = SV_BAND_SLICE_ALOFT, +
// SkyViewBandCentreTop at SV_BAND_SLICE_TOP.
float SkyViewBandSliceCentre(float sun_deg, float h) {
  float low = SkyViewBandCentre(sun_deg, min(h, SV_BAND_CENTRE_ALOFT_ALTITUDE.x));
  float l = max((SV_BAND_CENTRE_ALOFT_ALTITUDE.y - SV_BAND_CENTRE_ALOFT_ALTITUDE.x) / 1000.0, 1e-3);
  float a = clamp((h - SV_BAND_CENTRE_ALOFT_ALTITUDE.x) / 1000.0, 0.0, l);
  float g = 1.0 + SV_BAND_SLICE_ALOFT.x * a +
      (SV_BAND_SLICE_ALOFT.y - SV_BAND_SLICE_ALOFT.x) * a * a / (2.0 * l) +
      SkyViewBandCentreTop(h, SV_BAND_SLICE_TOP);
  return min(low * g, 45.0);
}

// The elevation (degrees) at which the slice of sun coordinate s_n and altitude h_n is read for
// a query at elevation_deg with the sun s_q and the maps' weight w_q (SkyViewBandWeight) at
// altitude h, azimuth cos_phi from the sun (the reader's band_slice_elevation): affine about
// SV_BAND_DEPTH h below the horizontal, the band (SkyViewBandSliceCentre) onto the band, faded as
// SkyViewBandRelative (aloft, SV_BAND_SLICE_AZIMUTH, also with -cos_phi).
float SkyViewBandSlice(float elevation_deg, float s_q, float w_q, float h, float s_n, float h_n,
                       float cos_phi) {
  float delta_q = SkyViewBandDepth(h);
  float delta_n = SkyViewBandDepth(h_n);
  float c = SkyViewBandSliceCentre(s_q, h);
  float c_n = SkyViewBandSliceCentre(s_n, h_n);
  float height_q = max(c * SV_BAND_ANTISOLAR + delta_q, 0.1);
  float height_n = max(c_n * SV_BAND_ANTISOLAR + delta_n, 0.1);
  float w = max(height_q, 0.5);
  // Aloft from -delta up through the horizontal (SV_BAND_SLICE_THROUGH).
  float through = smoothstep(SV_BAND_SLICE_THROUGH.x, SV_BAND_SLICE_THROUGH.y, h);
  float horizon = smoothstep(0.0, SV_BAND_HORIZON, elevation_deg) * (1.0 - through) +
      (elevation_deg >= -delta_q ? through : 0.0);
  // Aloft faded in with -cos_phi over SV_BAND_ANTISOLAR_RANGE, as the columns' map.
  float aloft = smoothstep(SV_BAND_SLICE_AZIMUTH.x, SV_BAND_SLICE_AZIMUTH.y, h);
  float azimuth = 1.0 - aloft * (1.0 - smoothstep(SV_BAND_ANTISOLAR_RANGE.x,
                                                  SV_BAND_ANTISOLAR_RANGE.y, -cos_phi));
  float fade = w_q * (1.0 - smoothstep(2.0 * w, 4.0 * w, elevation_deg)) * horizon * azimuth;
  float mapped = (elevation_deg + delta_q) * height_n / height_q - delta_n;
  return elevation_deg + fade * (mapped - elevation_deg);
}

// The sun node coordinate (degrees: the sun coordinate unwarped at h, clamped to the nodes) of
// the sun zenith cosine mu_s, the shift added to the sun's elevation and the warp's centre c (as
// SkyViewAltitudeSun; on the limb rows per altitude node, SkyViewRadiance).
float SkyViewSunAbove(float h, float shift, float c, float mu_s) {
  float s = degrees(asin(clamp(mu_s, -1.0, 1.0)) + shift);
  return clamp(SkyViewSunUnwarp(s, SkyViewWarpStrength(h), c), SkyViewSunNodeDeg(0),
               SkyViewSunNodeDeg(SV_N_SUN - 1));
}

// Altitude node k0 (and fraction tk) and sun node j0 (and tj) at altitude h with sun zenith
// cosine mu_s; shift: the angle added to the sun's elevation to make the sun coordinate (the
// horizon's dip atan(rho, bottom_radius), or on the limb SkyViewRadiance's shift); c: the
// warp's centre (SkyViewSunWarpCentre). above_deg: the sun node coordinate (degrees: the sun
// coordinate unwarped at h), clamped to the nodes.
void SkyViewAltitudeSun(float h, float shift, float c, float mu_s, out int k0, out float tk,
                        out int j0, out float tj, out float above_deg) {
  float thickness = top_radius - bottom_radius;
  // The altitude's base abscissa: (sqrt(e) + c (e^p - e^q)) times the last node's, e = h /
  // thickness, (c, p, q) = SV_ALT_MAP; k0 the node interval holding it (sv_alt_x).
  float e = clamp(h / thickness, 0.0, 1.0);
  float x = (sqrt(e) + SV_ALT_MAP.x * (pow(e, SV_ALT_MAP.y) - pow(e, SV_ALT_MAP.z))) *
      sv_alt_x[SV_N_ALT - 1];
  k0 = 0;
  for (int k = 1; k < SV_N_ALT - 1; ++k) {
    if (sv_alt_x[k] <= x) k0 = k;
  }
  tk = clamp((x - sv_alt_x[k0]) / (sv_alt_x[k0 + 1] - sv_alt_x[k0]), 0.0, 1.0);
  above_deg = SkyViewSunAbove(h, shift, c, mu_s);
  j0 = SkyViewSplit(SkyViewSunCoord(above_deg), SV_N_SUN, tj);
}

// One part's value at slice (k, j), row y, interpolated over the azimuth columns' stencil sc
// (as the reader's fetch), without the slice's scale.
vec3 SkyViewFetch(sampler2D part, int k, int j, int y, SvStencil sc) {
  vec3 v[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
  for (int m = 0; m < 4; ++m) {
    if (m >= sc.len) break;
    v[m] = texelFetch(part, ivec2(j * SV_N_AZ + SkyViewColumnTexel(sc.first + m), k * SV_N_VIEW + y),
                      0).rgb;
  }
  return SkyViewMix(sc, v);
}

// One part's value at slice (k, j) over the azimuth columns' stencil sc, each column m at its
// own rows' stencil rows[m] (the sky rows in low twilight, SkyViewBandRelative): over the rows
// within each column, then over the columns (as the reader's fetch_band), without the slice's
// scale.
vec3 SkyViewFetchBand(sampler2D part, int k, int j, SvStencil sc, SvStencil rows[4]) {
  vec3 v[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
  for (int m = 0; m < 4; ++m) {
    if (m >= sc.len) break;
    SvStencil sv = rows[m];
    vec3 w[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
    for (int n = 0; n < 4; ++n) {
      if (n >= sv.len) break;
      w[n] = texelFetch(part, ivec2(j * SV_N_AZ + SkyViewColumnTexel(sc.first + m),
                                    k * SV_N_VIEW + sv.first + n), 0).rgb;
    }
    v[m] = SkyViewMix(sv, w);
  }
  return SkyViewMix(sc, v);
}

// On the sky rows, the rows' stencil of each column m of sc in slice (altitude node k, sun node
// j) for a query at elevation_deg with the focus (c, k_q) at the sun coordinate s_q, altitude h and
// azimuth cos_phi from the sun, cos_cols the cosines of the azimuths of the slice's columns in
// the stencil sc (sv_az_node_cos) (the reader's band_rows): false where neither the query's nor
// the slice's maps' weight (SkyViewBandWeight) is positive (then the slice is read at the query's
// row).
bool SkyViewBandRows(float elevation_deg, float c, float k_q, float s_q, float h, float cos_phi,
                     vec4 cos_cols, int k, int j, out SvStencil rows[4]) {
  float h_n = sv_alt_nodes[k];
  float b = SkyViewWarpStrength(h_n);
  float s_n = SkyViewSunWarp(SkyViewSunNodeDeg(j), b);
  float c_n, k_n;
  SkyViewBandFocus(s_n, h_n, c_n, k_n);
  float w_q = SkyViewBandWeight(s_q, h), w_n = SkyViewBandWeight(s_n, h_n);
  if (w_q < 1e-6 && w_n < 1e-6) return false;
  float e_n = SkyViewBandSlice(elevation_deg, s_q, w_q, h, s_n, h_n, cos_phi);
  for (int m = 0; m < 4; ++m) {
    float e = SkyViewBandRelative(e_n, c_n, w_n, h_n, cos_phi, cos_cols[m]);
    rows[m] = SkyViewBandRowStencil(e, h, c_n, k_n, vec3(s_q, s_n, h_n));
  }
  return true;
}

// The radiance towards an observer at altitude h (inside the atmosphere; rho as above) looking
// along view_ray (zenith cosine mu) with the sun along sun_direction (zenith cosine mu_s);
// `up` is the observer's unit vertical.
vec3 SkyViewRadiance(float h, float rho, vec3 up, vec3 view_ray, vec3 sun_direction) {
  h = clamp(h, 0.0, top_radius - bottom_radius);
  float r = bottom_radius + h;
  float mu = clamp(dot(view_ray, up), -1.0, 1.0);
  float mu_s = clamp(dot(sun_direction, up), -1.0, 1.0);
  float nu = dot(view_ray, sun_direction);
  // The view row within its segment, relative to the observer's horizon (cos = -rho / r).
  int segment;
  float row;
  // The horizon's dip, and on the limb the angle between the observer's and the ray's tangent
  // point's verticals (gamma) and the tangent point's horizon's dip (dip_t).
  float dip = atan(rho, bottom_radius);
  float gamma = 0.0, dip_t = 0.0, h_t = h, y_limb = 0.0;
  if (mu >= 0.0) {
    // Zenith to horizontal: theta = (pi/2) (1 - (1 - x)^2); 1 - theta / (pi/2) = asin(mu) / (pi/2).
    // (The row below: at low altitude in twilight the rows concentrate on the band above the
    // earth's shadow, at the ray's sun coordinate.)
    segment = 0;
    row = 0.0;
  } else if (mu > -rho / r) {
    // Horizontal to horizon, at the depth of the ray's tangent radius r_t = r sqrt(1 - mu^2):
    // y = (r - r_t) / h, with r - r_t = r mu^2 / (1 + sqrt(1 - mu^2)), y = 2x^2 - x^3.
    segment = 1;
    float r_minus_rt = r * mu * mu / (1.0 + sqrt(1.0 - mu * mu));
    y_limb = h > 0.0 ? clamp(r_minus_rt / h, 0.0, 1.0) : 1.0;
    // (The row: each slice's own, SkyViewLimbFocus at the slice's sun and altitude, below.)
    row = float(SV_N_VIEW_SKY) + SkyViewLimbRow(y_limb) * float(SV_N_VIEW_LIMB - 1);
    h_t = max(h - r_minus_rt, 0.0);
    gamma = asin(-mu);
    dip_t = atan(sqrt(h_t * (2.0 * bottom_radius + h_t)), bottom_radius);
  } else {
    // Horizon to nadir: theta = theta_h + (pi - theta_h) x^2, theta_h = pi/2 + dip.
    segment = 2;
    float x = sqrt(clamp((asin(-mu) - dip) / (0.5 * PI - dip), 0.0, 1.0));
    row = float(SV_N_VIEW_UP) + x * float(SV_N_VIEW_DOWN - 1);
  }
  // The azimuth between the view and the sun around the vertical.
  vec3 view_h = view_ray - mu * up;
  vec3 sun_h = sun_direction - mu_s * up;
  float phi = dot(view_h, view_h) * dot(sun_h, sun_h) > 1e-12 ?
      atan(length(cross(view_h, sun_h)), dot(view_h, sun_h)) : 0.0;
  // The sun coordinate: the sun's elevation above the observer's horizon, on the limb above the
  // horizon of the ray's tangent point (the reader's sun_shift).
  float shift = dip;
  if (segment == 1) {
    // Aloft away from the sun back towards the observer's horizon (the reader's limb_near_end).
    float w = SkyViewLimbTangentWeight(SkyViewCos(phi), h, h - h_t);
    shift = dip + w * (gamma * SkyViewCos(phi) + dip_t - dip);
  } else if (segment == 0) {
    // Aloft, towards the sun: the sun's elevation at the ray's exit through the top, alpha the
    // central angle to it (the reader's sun_shift), weighted by SkyViewExitAzimuth(cos(phi)).
    float w = smoothstep(SV_SKY_EXIT_ALTITUDE.x, SV_SKY_EXIT_ALTITUDE.y, h);
    float toward = SkyViewExitAzimuth(SkyViewCos(phi));
    if (w > 0.0 && toward != 0.0) {
      float x_top = DistanceToTopAtmosphereBoundary(r, mu);
      float exit_angle = atan(x_top * sqrt(max(1.0 - mu * mu, 0.0)), r + x_top * mu);
      shift = dip + w * exit_angle * toward;
    }
  }
  // On the sky rows in low twilight, each slice's and azimuth column's own rows
  // (SkyViewBandRows): the query's elevation moved to where it lies relative to the band at the
  // slice's sun and altitude and at the column's azimuth.
  float band_c = 0.0, band_k = 0.0, elevation = 0.0;
  float s_q = degrees(asin(mu_s) + shift);
  if (segment < 2) {
    // The sky rows' focus (the reader's sky_row_focus) at the sun coordinate.
    SkyViewBandFocus(s_q, h, band_c, band_k);
    elevation = degrees(asin(mu));
  }
  if (segment == 0) {
    row = SkyViewSkyRow(elevation, band_c * SkyViewFocusPlace(band_c, h), band_k,
                        SkyViewFocusWidth(band_c, h)) *
        float(SV_N_VIEW_SKY - 1);
  }
  int lo = segment == 0 ? 0 : segment == 1 ? SV_N_VIEW_SKY : SV_N_VIEW_UP;
  int hi = segment == 0 ? SV_N_VIEW_SKY - 1 : segment == 1 ? SV_N_VIEW_UP - 1 : SV_N_VIEW - 1;
  SvStencil sv = SkyViewStencil(row, lo, hi, false, 0.0);
  int k0, j0;
  float tk, tj, above_deg;
  SkyViewAltitudeSun(h, shift, SkyViewSunWarpCentre(h, segment, SkyViewCos(phi)), mu_s, k0, tk,
                     j0, tj, above_deg);
  SvStencil sa = SkyViewAltitudeStencil(float(k0) + tk);
  SvStencil ss_q = SkyViewStencil(float(j0) + tj, 0, SV_N_SUN - 1, true, above_deg);
  // Each altitude node's columns (the reader's node_column): from the query's column coordinate
  // (below SV_AZ_NODE_READ.x) to the azimuth's coordinate in the node's own map (above
  // SV_AZ_NODE_READ.y; SkyViewAzimuthColumn at the node's altitude), and the cosines of the
  // azimuths of its stencil's columns (for SkyViewBandRows).
  float column_q = SkyViewAzimuthColumn(phi, h);
  float node_read = smoothstep(SV_AZ_NODE_READ.x, SV_AZ_NODE_READ.y, h);
  SvStencil sc_n[4];
  vec4 cos_cols[4];
  for (int a = 0; a < 4; ++a) {
    if (a >= sa.len) break;
    int k = sa.first + a;
    float column = node_read > 0.0 ?
        column_q + node_read * (SkyViewAzimuthColumn(phi, sv_alt_nodes[k]) - column_q) : column_q;
    sc_n[a] = SkyViewColumnStencil(column);
    for (int m = 0; m < 4; ++m) {
      int col = SkyViewColumnTexel(sc_n[a].first + m);
      float cos_n = sv_az_node_cos[k * SV_N_AZ + col];
      // Below SV_AZ_NODE_READ.y blended from the column's azimuth at the query's altitude (the
      // reader's band_rows; there the map has no focus, SkyViewAzimuthNode).
      cos_cols[a][m] = node_read >= 1.0 || segment == 2 ? cos_n :
          node_read > 0.0 ? (1.0 - node_read) * SkyViewCos(SkyViewAzimuthNode(col, h)) + node_read * cos_n :
          SkyViewCos(SkyViewAzimuthNode(col, h));
    }
  }
  // The ray's length: to the ground below the horizon, else to the top (closed forms, the
  // ground's as rho^2 / (-r mu + sqrt(...)) to avoid the cancellation near the horizon).
  float d;
  if (segment == 2) {
    float disc = max(r * mu * r * mu - rho * rho, 0.0);
    float den = -r * mu + sqrt(disc);
    d = den > 0.0 ? rho * rho / den : 0.0;
  } else {
    d = DistanceToTopAtmosphereBoundary(r, mu);
  }
  vec3 parts[2];
  for (int part = 0; part < 2; ++part) {
    vec3 by_altitude[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
    for (int a = 0; a < 4; ++a) {
      if (a >= sa.len) break;
      vec3 by_sun[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
      SvStencil sc = sc_n[a];
      // On the limb rows, the node read at the query's sun coordinate formed with the node's
      // tangent-point weight (the reader's limb_node_shift: at the node's altitude h_n and the
      // depth y_limb h_n aloft, the query's exponential below, the query's weight higher up),
      // without the sun nodes read too deep.
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
      for (int s = 0; s < 4; ++s) {
        if (s >= ss.len) break;
        vec3 value;
        SvStencil band_rows[4];
        if (segment < 2 && SkyViewBandRows(elevation, band_c, band_k, s_q, h, SkyViewCos(phi),
                                            cos_cols[a], sa.first + a, ss.first + s, band_rows)) {
          int k = sa.first + a, j = ss.first + s;
          value = part == 0 ? SkyViewFetchBand(skyview_rayleigh, k, j, sc, band_rows) :
                              SkyViewFetchBand(skyview_mie, k, j, sc, band_rows);
        } else {
          // On the limb rows, the slice's own rows at the query's depth (the reader's
          // limb_row_focused at the slice's sun and altitude).
          SvStencil sv_n = sv;
          if (segment == 1) {
            float h_n = sv_alt_nodes[sa.first + a];
            float b_n = SkyViewWarpStrength(h_n);
            float s_n = SkyViewSunWarp(SkyViewSunNodeDeg(ss.first + s), b_n);
            vec2 limb_n = SkyViewLimbFocus(s_n, h_n);
            float y_n = SkyViewLimbSliceDepth(y_limb, s_k, h, s_n, h_n);
            sv_n = SkyViewStencil(float(SV_N_VIEW_SKY) +
                                      SkyViewFocusCoord(SkyViewLimbRow(y_n), limb_n.x, limb_n.y) *
                                          float(SV_N_VIEW_LIMB - 1),
                                  lo, hi, false, 0.0);
          }
          vec3 by_row[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
          for (int v = 0; v < 4; ++v) {
            if (v >= sv_n.len) break;
            int k = sa.first + a, j = ss.first + s, y = sv_n.first + v;
            by_row[v] = part == 0 ? SkyViewFetch(skyview_rayleigh, k, j, y, sc) :
                                    SkyViewFetch(skyview_mie, k, j, y, sc);
          }
          value = SkyViewMix(sv_n, by_row);
        }
        // The slice's scale (the interpolation commutes with a common factor).
        ivec2 slice = ivec2(ss.first + s, sa.first + a);
        by_sun[s] = value * (part == 0 ?
            texelFetch(skyview_scale_rayleigh, slice, 0).rgb :
            texelFetch(skyview_scale_mie, slice, 0).rgb);
      }
      by_altitude[a] = SkyViewMix(ss, by_sun);
    }
    parts[part] = SkyViewMix(sa, by_altitude) * d;
  }
  return parts[0] * RayleighPhaseFunction(nu) + parts[1] * AerosolPhaseFunction(nu);
}

// ---- Bruneton's three rendering functions, on this layout ----
vec3 GetSkyRadiance(vec3 camera, vec3 view_ray, vec3 sun_direction, out vec3 transmittance) {
  float r = length(camera);
  float rmu = dot(camera, view_ray);
  if (r > top_radius) {
    // Above the top: start where the view enters the atmosphere (nothing if it misses it).
    float disc = rmu * rmu + SquareDifference(top_radius, r);
    float to_top = -rmu - sqrt(max(disc, 0.0));
    if (disc < 0.0 || to_top < 0.0) {
      transmittance = vec3(1.0);
      return vec3(0.0);
    }
    camera = camera + view_ray * to_top;
    r = top_radius;
    rmu += to_top;
  }
  float mu = rmu / r;
  transmittance = RayIntersectsGround(r, mu) ? vec3(0.0) :
      GetTransmittanceToTopAtmosphereBoundary(r, mu);
  float h = max(r - bottom_radius, 0.0);
  return SkyViewRadiance(h, sqrt(h * (2.0 * bottom_radius + h)), camera / r, view_ray,
                         sun_direction);
}

// The aerial perspective between the camera and the point camera + offset (a renderer knows
// the offset: view ray x depth) and the transmittance between them: Bruneton & Neyret's
// construction, L(camera, v) - T(camera -> point) L(point, v) (as SkyViewReader's
// sky_radiance_to_point), T from Bruneton's transmittance texture.
vec3 GetSkyRadianceToPointOffset(vec3 camera, vec3 offset, vec3 sun_direction,
                                 out vec3 transmittance) {
  vec3 view_ray = normalize(offset);
  float d = length(offset);
  float r = length(camera);
  float rmu = dot(camera, view_ray);
  EnterAtmosphere(camera, view_ray, r, rmu, d);
  float mu = rmu / r;
  transmittance = GetTransmittance(r, mu, d, RayIntersectsGround(r, mu));
  float h = max(r - bottom_radius, 0.0);
  vec3 near = SkyViewRadiance(h, sqrt(h * (2.0 * bottom_radius + h)), camera / r, view_ray,
                              sun_direction);
  // The far end: its altitude and rho from RhoAlong (not from its 32-bit radius).
  float r_p;
  float rho_p = RhoAlong(r, mu, d, r_p);
  vec3 up_p = normalize(camera + view_ray * d);
  vec3 far = SkyViewRadiance(r_p - bottom_radius, rho_p, up_p, view_ray, sun_direction);
  return near - transmittance * far;
}

vec3 GetSkyRadianceToPoint(vec3 camera, vec3 point, vec3 sun_direction,
                           out vec3 transmittance) {
  return GetSkyRadianceToPointOffset(camera, point - camera, sun_direction, transmittance);
}

// Returns the sun's irradiance on the surface; the sky's in sky_irradiance (the table on the
// altitude x sun nodes, interpolated like the sky, x (top - r), x his tilt factor (1 + n.up)/2).
vec3 GetSunAndSkyIrradiance(vec3 point, vec3 normal, vec3 sun_direction,
                            out vec3 sky_irradiance) {
  float r = length(point);
  float mu_s = dot(point, sun_direction) / r;
  float h = clamp(r - bottom_radius, 0.0, top_radius - bottom_radius);
  int k0, j0;
  float tk, tj, above_deg;
  SkyViewAltitudeSun(h, atan(sqrt(h * (2.0 * bottom_radius + h)), bottom_radius), 0.0, mu_s, k0,
                     tk, j0, tj, above_deg);
  vec3 lo = GeoMix(texelFetch(skyview_irradiance, ivec2(j0, k0), 0).rgb,
                   texelFetch(skyview_irradiance, ivec2(j0 + 1, k0), 0).rgb, tj);
  vec3 hi = GeoMix(texelFetch(skyview_irradiance, ivec2(j0, k0 + 1), 0).rgb,
                   texelFetch(skyview_irradiance, ivec2(j0 + 1, k0 + 1), 0).rgb, tj);
  sky_irradiance = GeoMix(lo, hi, tk) * (top_radius - bottom_radius - h) *
      (1.0 + dot(normal, point) / r) * 0.5;
  return solar_irradiance * GetTransmittanceToSun(r, mu_s) *
      max(dot(normal, sun_direction), 0.0);
}
