// skybake's reference real-time client (GLSL ES 3.0, WebGL2): the sky, the aerial perspective
// and the sun and sky light from the texture bundle of `skybake lut` / GET /v1/lut (docs/lut.md),
// with Bruneton's functions GetSkyRadiance, GetSkyRadianceToPoint and GetSunAndSkyIrradiance
// (Bruneton & Neyret 2008, "Precomputed Atmospheric Scattering"; Bruneton 2017, "Precomputed
// Atmospheric Scattering: a New Implementation", functions.glsl), written from his documentation
// (no light shafts; the combined scattering layout of the RGB bundle). The CPU twin is
// crates/lut/src/reader.rs (`skybake lut-eval`); tools/browser/lut_test.mjs checks one against
// the other. Lengths in metres, radiance in the bundle's unit (mW m^-2 sr^-1 nm^-1).
//
// The including program defines SKY_VIEW (the viewer's panorama) or PROBES (queries read back
// from a float framebuffer) before this file; for the `skyview` layout also SKYVIEW_LAYOUT, and
// appends web/lut/skyview.glsl (that layout's versions of his three functions) after it. 32-bit floats at planetary radii: where his
// expressions subtract squares of radii (r^2 - R^2) they are written as products of a difference
// and a sum, and rho (his r coordinate) at the far end of a ray is computed from that point's
// altitude (RhoAlong) — the same values, without the cancellation. The *Rho variants take rho.

precision highp float;
precision highp sampler2D;
precision highp sampler3D;

// ---- the bundle: textures and his AtmosphereParameters (from the manifest) ----
uniform sampler2D transmittance_texture;
#ifndef SKYVIEW_LAYOUT
uniform sampler3D scattering_texture;
uniform sampler2D irradiance_texture;
#endif
uniform float bottom_radius;
uniform float top_radius;
uniform float mu_s_min;
uniform float sun_angular_radius;
uniform float mie_phase_function_g;
uniform vec3 solar_irradiance;
uniform vec3 rayleigh_scattering;
uniform vec3 mie_scattering;

const float TRANSMITTANCE_TEXTURE_WIDTH = 256.0;
const float TRANSMITTANCE_TEXTURE_HEIGHT = 64.0;
const float SCATTERING_TEXTURE_R_SIZE = 32.0;
const float SCATTERING_TEXTURE_MU_SIZE = 128.0;
const float SCATTERING_TEXTURE_MU_S_SIZE = 32.0;
const float SCATTERING_TEXTURE_NU_SIZE = 8.0;
const float IRRADIANCE_TEXTURE_WIDTH = 64.0;
const float IRRADIANCE_TEXTURE_HEIGHT = 16.0;
const float PI = 3.14159265358979;

float ClampCosine(float mu) { return clamp(mu, -1.0, 1.0); }
float SafeSqrt(float a) { return sqrt(max(a, 0.0)); }
float ClampRadius(float r) { return clamp(r, bottom_radius, top_radius); }

// r^2 - R^2 for radii r, R.
float SquareDifference(float r, float R) { return (r - R) * (r + R); }

float DistanceToTopAtmosphereBoundary(float r, float mu) {
  // r^2 (mu^2 - 1) + top^2
  float discriminant = SquareDifference(top_radius, r) + r * mu * r * mu;
  return max(-r * mu + SafeSqrt(discriminant), 0.0);
}

bool RayIntersectsGround(float r, float mu) {
  return mu < 0.0 && SquareDifference(bottom_radius, r) + r * mu * r * mu >= 0.0;
}

// The start of his GetSkyRadianceToPoint: a camera above the top of the atmosphere moves to
// where the segment along view_ray enters it (r, r mu and the length d left updated). Both
// layouts' GetSkyRadianceToPointOffset use it.
void EnterAtmosphere(inout vec3 camera, vec3 view_ray, inout float r, inout float rmu,
                     inout float d) {
  float distance_to_top_atmosphere_boundary =
      -rmu - sqrt(rmu * rmu + SquareDifference(top_radius, r));
  if (distance_to_top_atmosphere_boundary > 0.0) {
    camera = camera + view_ray * distance_to_top_atmosphere_boundary;
    r = top_radius;
    rmu += distance_to_top_atmosphere_boundary;
    d -= distance_to_top_atmosphere_boundary;
  }
}

float GetTextureCoordFromUnitRange(float x, float texture_size) {
  return 0.5 / texture_size + x * (1.0 - 1.0 / texture_size);
}

// rho = sqrt(r^2 - bottom^2), his distance to the horizon and the r coordinate of his textures.
float Rho(float r) { return SafeSqrt(SquareDifference(r, bottom_radius)); }

// The point at distance d along the ray (r, mu): its radius r_d and its rho, the latter from the
// point's altitude rather than from its 32-bit radius (which holds r_d - bottom to 0.5 m only,
// and near the ground his rho = sqrt(2 bottom h) is steep in the altitude h).
float RhoAlong(float r, float mu, float d, out float r_d) {
  float delta = d * (d + 2.0 * r * mu);  // r_d^2 - r^2
  float h_d = (r - bottom_radius) + delta / (r + sqrt(max(r * r + delta, 0.0)));
  h_d = clamp(h_d, 0.0, top_radius - bottom_radius);
  r_d = bottom_radius + h_d;
  return sqrt(h_d * (2.0 * bottom_radius + h_d));
}

// ---- transmittance ----
vec2 GetTransmittanceTextureUvFromRRhoMu(float r, float rho, float mu) {
  float H = sqrt(SquareDifference(top_radius, bottom_radius));
  float d = DistanceToTopAtmosphereBoundary(r, mu);
  float d_min = top_radius - r;
  float d_max = rho + H;
  float x_mu = d_max > d_min ? (d - d_min) / (d_max - d_min) : 0.0;
  float x_r = rho / H;
  return vec2(GetTextureCoordFromUnitRange(x_mu, TRANSMITTANCE_TEXTURE_WIDTH),
              GetTextureCoordFromUnitRange(x_r, TRANSMITTANCE_TEXTURE_HEIGHT));
}

vec2 GetTransmittanceTextureUvFromRMu(float r, float mu) {
  return GetTransmittanceTextureUvFromRRhoMu(r, Rho(r), mu);
}

vec3 GetTransmittanceToTopAtmosphereBoundaryRho(float r, float rho, float mu) {
  return texture(transmittance_texture, GetTransmittanceTextureUvFromRRhoMu(r, rho, mu)).rgb;
}

vec3 GetTransmittanceToTopAtmosphereBoundary(float r, float mu) {
  return GetTransmittanceToTopAtmosphereBoundaryRho(r, Rho(r), mu);
}

vec3 SafeRatio(vec3 num, vec3 den) {
  return vec3(den.x > 0.0 ? min(num.x / den.x, 1.0) : 0.0,
              den.y > 0.0 ? min(num.y / den.y, 1.0) : 0.0,
              den.z > 0.0 ? min(num.z / den.z, 1.0) : 0.0);
}

vec3 GetTransmittance(float r, float mu, float d, bool ray_r_mu_intersects_ground) {
  float r_d;
  float rho_d = RhoAlong(r, mu, d, r_d);
  float rho = Rho(r);
  float mu_d = ClampCosine((r * mu + d) / r_d);
  if (ray_r_mu_intersects_ground) {
    return SafeRatio(GetTransmittanceToTopAtmosphereBoundaryRho(r_d, rho_d, -mu_d),
                     GetTransmittanceToTopAtmosphereBoundaryRho(r, rho, -mu));
  }
  return SafeRatio(GetTransmittanceToTopAtmosphereBoundaryRho(r, rho, mu),
                   GetTransmittanceToTopAtmosphereBoundaryRho(r_d, rho_d, mu_d));
}

vec3 GetTransmittanceToSun(float r, float mu_s) {
  float sin_theta_h = bottom_radius / r;
  float cos_theta_h = -sqrt(max(1.0 - sin_theta_h * sin_theta_h, 0.0));
  return GetTransmittanceToTopAtmosphereBoundary(r, mu_s) *
      smoothstep(-sin_theta_h * sun_angular_radius, sin_theta_h * sun_angular_radius,
                 mu_s - cos_theta_h);
}

// ---- phase functions ----
float RayleighPhaseFunction(float nu) {
  return 3.0 / (16.0 * PI) * (1.0 + nu * nu);
}

float MiePhaseFunction(float g, float nu) {
  float k = 3.0 / (8.0 * PI) * (1.0 - g * g) / (2.0 + g * g);
  return k * (1.0 + nu * nu) / pow(max(1.0 + g * g - 2.0 * g * nu, 1e-12), 1.5);
}

#ifndef SKYVIEW_LAYOUT
// ---- scattering ----
vec4 GetScatteringTextureUvwzFromRRhoMuMuSNu(float r, float rho, float mu, float mu_s, float nu,
                                             bool ray_r_mu_intersects_ground) {
  float H = sqrt(SquareDifference(top_radius, bottom_radius));
  float u_r = GetTextureCoordFromUnitRange(rho / H, SCATTERING_TEXTURE_R_SIZE);
  float r_mu = r * mu;
  // r_mu^2 - r^2 + bottom^2
  float discriminant = r_mu * r_mu - rho * rho;
  float u_mu;
  if (ray_r_mu_intersects_ground) {
    float d = -r_mu - SafeSqrt(discriminant);
    float d_min = rho * rho / (r + bottom_radius);  // r - bottom
    float d_max = rho;
    u_mu = 0.5 - 0.5 * GetTextureCoordFromUnitRange(
        d_max == d_min ? 0.0 : (d - d_min) / (d_max - d_min), SCATTERING_TEXTURE_MU_SIZE / 2.0);
  } else {
    float d = -r_mu + SafeSqrt(discriminant + H * H);
    float d_min = top_radius - r;
    float d_max = rho + H;
    u_mu = 0.5 + 0.5 * GetTextureCoordFromUnitRange(
        (d - d_min) / (d_max - d_min), SCATTERING_TEXTURE_MU_SIZE / 2.0);
  }
  float d = DistanceToTopAtmosphereBoundary(bottom_radius, mu_s);
  float d_min = top_radius - bottom_radius;
  float d_max = H;
  float a = (d - d_min) / (d_max - d_min);
  float D = DistanceToTopAtmosphereBoundary(bottom_radius, mu_s_min);
  float A = (D - d_min) / (d_max - d_min);
  float u_mu_s = GetTextureCoordFromUnitRange(max(1.0 - a / A, 0.0) / (1.0 + a),
                                              SCATTERING_TEXTURE_MU_S_SIZE);
  float u_nu = (nu + 1.0) / 2.0;
  return vec4(u_nu, u_mu_s, u_mu, u_r);
}

vec4 GetScatteringTextureUvwzFromRMuMuSNu(float r, float mu, float mu_s, float nu,
                                          bool ray_r_mu_intersects_ground) {
  return GetScatteringTextureUvwzFromRRhoMuMuSNu(r, Rho(r), mu, mu_s, nu,
                                                 ray_r_mu_intersects_ground);
}

vec3 GetExtrapolatedSingleMieScattering(vec4 scattering) {
  if (scattering.r <= 0.0 || mie_scattering.r <= 0.0) {
    return vec3(0.0);
  }
  return scattering.rgb * scattering.a / scattering.r *
      (rayleigh_scattering.r / mie_scattering.r) * (mie_scattering / rayleigh_scattering);
}

// The combined texture (RGB: Rayleigh + multiple scattering, A: single Mie of R), interpolated
// over nu by hand between the two nearest nu slices of the 3-D texture.
vec4 GetCombinedScatteringRaw(float r, float rho, float mu, float mu_s, float nu,
                              bool ray_r_mu_intersects_ground) {
  vec4 uvwz = GetScatteringTextureUvwzFromRRhoMuMuSNu(r, rho, mu, mu_s, nu,
                                                      ray_r_mu_intersects_ground);
  float tex_coord_x = uvwz.x * (SCATTERING_TEXTURE_NU_SIZE - 1.0);
  float tex_x = min(floor(tex_coord_x), SCATTERING_TEXTURE_NU_SIZE - 1.0);
  float lerp = tex_coord_x - tex_x;
  vec3 uvw0 = vec3((tex_x + uvwz.y) / SCATTERING_TEXTURE_NU_SIZE, uvwz.z, uvwz.w);
  vec3 uvw1 = vec3((tex_x + 1.0 + uvwz.y) / SCATTERING_TEXTURE_NU_SIZE, uvwz.z, uvwz.w);
  return texture(scattering_texture, uvw0) * (1.0 - lerp) +
      texture(scattering_texture, uvw1) * lerp;
}

vec3 GetCombinedScattering(float r, float mu, float mu_s, float nu,
                           bool ray_r_mu_intersects_ground, out vec3 single_mie_scattering) {
  vec4 combined = GetCombinedScatteringRaw(r, Rho(r), mu, mu_s, nu, ray_r_mu_intersects_ground);
  single_mie_scattering = GetExtrapolatedSingleMieScattering(combined);
  return combined.rgb;
}

// ---- his three rendering functions ----
vec3 GetSkyRadiance(vec3 camera, vec3 view_ray, vec3 sun_direction, out vec3 transmittance) {
  float r = length(camera);
  float rmu = dot(camera, view_ray);
  float distance_to_top_atmosphere_boundary =
      -rmu - sqrt(rmu * rmu + SquareDifference(top_radius, r));
  if (distance_to_top_atmosphere_boundary > 0.0) {
    camera = camera + view_ray * distance_to_top_atmosphere_boundary;
    r = top_radius;
    rmu += distance_to_top_atmosphere_boundary;
  } else if (r > top_radius) {
    transmittance = vec3(1.0);
    return vec3(0.0);
  }
  float mu = rmu / r;
  float mu_s = dot(camera, sun_direction) / r;
  float nu = dot(view_ray, sun_direction);
  bool ray_r_mu_intersects_ground = RayIntersectsGround(r, mu);
  transmittance = ray_r_mu_intersects_ground ? vec3(0.0) :
      GetTransmittanceToTopAtmosphereBoundary(r, mu);
  vec3 single_mie_scattering;
  vec3 scattering = GetCombinedScattering(r, mu, mu_s, nu, ray_r_mu_intersects_ground,
                                          single_mie_scattering);
  return scattering * RayleighPhaseFunction(nu) +
      single_mie_scattering * MiePhaseFunction(mie_phase_function_g, nu);
}

// His GetSkyRadianceToPoint with the point given by its offset from the camera: in 32-bit floats
// the difference of two positions ~6.4e6 m from the centre loses half a metre, which moves
// grazing rays across texels of his mu mapping; a renderer knows the offset (view ray x depth).
vec3 GetSkyRadianceToPointOffset(vec3 camera, vec3 offset, vec3 sun_direction,
                                 out vec3 transmittance) {
  vec3 view_ray = normalize(offset);
  float d = length(offset);
  float r = length(camera);
  float rmu = dot(camera, view_ray);
  EnterAtmosphere(camera, view_ray, r, rmu, d);
  float mu = rmu / r;
  float mu_s = dot(camera, sun_direction) / r;
  float nu = dot(view_ray, sun_direction);
  bool ray_r_mu_intersects_ground = RayIntersectsGround(r, mu);
  transmittance = GetTransmittance(r, mu, d, ray_r_mu_intersects_ground);
  vec4 s = GetCombinedScatteringRaw(r, Rho(r), mu, mu_s, nu, ray_r_mu_intersects_ground);
  float r_p;
  float rho_p = RhoAlong(r, mu, d, r_p);
  float mu_p = (r * mu + d) / r_p;
  float mu_s_p = (r * mu_s + d * nu) / r_p;
  vec4 s_p = GetCombinedScatteringRaw(r_p, rho_p, mu_p, mu_s_p, nu, ray_r_mu_intersects_ground);
  vec3 scattering = s.rgb - transmittance * s_p.rgb;
  float single_mie_r = s.a - transmittance.r * s_p.a;
  vec3 single_mie_scattering = GetExtrapolatedSingleMieScattering(vec4(scattering, single_mie_r));
  // His guard against artefacts when the sun is below the horizon.
  single_mie_scattering = single_mie_scattering * smoothstep(0.0, 0.01, mu_s);
  return scattering * RayleighPhaseFunction(nu) +
      single_mie_scattering * MiePhaseFunction(mie_phase_function_g, nu);
}

vec3 GetSkyRadianceToPoint(vec3 camera, vec3 point, vec3 sun_direction,
                           out vec3 transmittance) {
  return GetSkyRadianceToPointOffset(camera, point - camera, sun_direction, transmittance);
}

vec2 GetIrradianceTextureUvFromRMuS(float r, float mu_s) {
  float x_r = (r - bottom_radius) / (top_radius - bottom_radius);
  float x_mu_s = mu_s * 0.5 + 0.5;
  return vec2(GetTextureCoordFromUnitRange(x_mu_s, IRRADIANCE_TEXTURE_WIDTH),
              GetTextureCoordFromUnitRange(x_r, IRRADIANCE_TEXTURE_HEIGHT));
}

// Returns the sun's irradiance on the surface; the sky's in sky_irradiance.
vec3 GetSunAndSkyIrradiance(vec3 point, vec3 normal, vec3 sun_direction,
                            out vec3 sky_irradiance) {
  float r = length(point);
  float mu_s = dot(point, sun_direction) / r;
  sky_irradiance = texture(irradiance_texture, GetIrradianceTextureUvFromRMuS(r, mu_s)).rgb *
      (1.0 + dot(normal, point) / r) * 0.5;
  return solar_irradiance * GetTransmittanceToSun(r, mu_s) *
      max(dot(normal, sun_direction), 0.0);
}
#else
// The skyview layout (SKYVIEW_LAYOUT): the same three functions, defined in web/lut/skyview.glsl,
// which the including program appends after this file.
vec3 GetSkyRadiance(vec3 camera, vec3 view_ray, vec3 sun_direction, out vec3 transmittance);
vec3 GetSkyRadianceToPointOffset(vec3 camera, vec3 offset, vec3 sun_direction,
                                 out vec3 transmittance);
vec3 GetSkyRadianceToPoint(vec3 camera, vec3 point, vec3 sun_direction,
                           out vec3 transmittance);
vec3 GetSunAndSkyIrradiance(vec3 point, vec3 normal, vec3 sun_direction,
                            out vec3 sky_irradiance);
#endif

// ---- the viewer's panorama: sky, sun disk, and the planet as the ground plane ----
#ifdef SKY_VIEW
uniform vec3 camera;          // m from the planet's centre
uniform vec3 sun_direction;
uniform vec3 ground_albedo;
uniform float exposure;       // display value = 1 - exp(-radiance * exposure)
uniform vec2 view_size;       // pixels
uniform vec2 elevation_range; // radians, bottom and top of the panorama
in vec2 frag_uv;
out vec4 frag_colour;

void main() {
  // Azimuth -pi..pi across (the sun's at the centre), elevation bottom to top.
  float azimuth = (frag_uv.x * 2.0 - 1.0) * PI;
  float elevation = mix(elevation_range.x, elevation_range.y, frag_uv.y);
  vec3 up = normalize(camera);
  vec3 sun_horizontal = sun_direction - up * dot(sun_direction, up);
  vec3 east = length(sun_horizontal) > 1e-6 ? normalize(sun_horizontal) :
      normalize(cross(up, vec3(0.0, 1.0, 0.0)));
  vec3 north = cross(up, east);
  vec3 view = normalize(cos(elevation) * (cos(azimuth) * east + sin(azimuth) * north) +
                        sin(elevation) * up);
  vec3 radiance;
  // The ground: the planet's surface, lit by the sun and the sky (his demo's Lambertian ground)
  // and seen through the aerial perspective.
  float r = length(camera);
  float rmu = dot(camera, view);
  float disc = rmu * rmu + SquareDifference(bottom_radius, r);
  float distance_to_ground = disc >= 0.0 && rmu < 0.0 ? -rmu - sqrt(disc) : -1.0;
  if (distance_to_ground > 0.0) {
    vec3 point = camera + view * distance_to_ground;
    vec3 normal = normalize(point);
    vec3 sky_irradiance;
    vec3 sun_irradiance = GetSunAndSkyIrradiance(point, normal, sun_direction, sky_irradiance);
    vec3 transmittance;
    vec3 in_scatter = GetSkyRadianceToPointOffset(camera, view * distance_to_ground,
                                                  sun_direction, transmittance);
    radiance = ground_albedo / PI * (sun_irradiance + sky_irradiance) * transmittance +
        in_scatter;
  } else {
    vec3 transmittance;
    radiance = GetSkyRadiance(camera, view, sun_direction, transmittance);
    if (dot(view, sun_direction) > cos(sun_angular_radius)) {
      radiance += transmittance * solar_irradiance /
          (PI * sun_angular_radius * sun_angular_radius);
    }
  }
  vec3 colour = pow(vec3(1.0) - exp(-radiance * exposure), vec3(1.0 / 2.2));
  frag_colour = vec4(colour, 1.0);
}
#endif

// ---- probes: one query per pixel of an N x 1 float framebuffer ----
#ifdef PROBES
// Query i in column i: row 0 camera or point (xyz) and the function (w: 0 GetSkyRadiance,
// 1 GetSkyRadianceToPoint, 2 GetSunAndSkyIrradiance); row 1 view ray, the point's offset from
// the camera, or the normal; row 2 sun.
uniform sampler2D queries;
uniform int probe_output;     // 0: radiance (sun irradiance); 1: transmittance (sky irradiance)
out vec4 frag_value;

void main() {
  int i = int(gl_FragCoord.x);
  vec4 q0 = texelFetch(queries, ivec2(i, 0), 0);
  vec3 q1 = texelFetch(queries, ivec2(i, 1), 0).xyz;
  vec3 sun = normalize(texelFetch(queries, ivec2(i, 2), 0).xyz);
  vec3 first;
  vec3 second;
  if (q0.w < 0.5) {
    first = GetSkyRadiance(q0.xyz, normalize(q1), sun, second);
  } else if (q0.w < 1.5) {
    first = GetSkyRadianceToPointOffset(q0.xyz, q1, sun, second);
  } else {
    first = GetSunAndSkyIrradiance(q0.xyz, normalize(q1), sun, second);
  }
  frag_value = vec4(probe_output == 0 ? first : second, 1.0);
}
#endif
