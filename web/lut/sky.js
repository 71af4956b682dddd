// skybake's live sky: the texture bundle of GET /v1/lut (docs/lut.md) fetched once, decoded
// (lut-exr.js), uploaded as WebGL2 textures and rendered every frame — no request per frame — by
// the shader of its layout (the manifest's `format`): `bruneton2017`, Bruneton's functions
// (lut-atmosphere.glsl; Bruneton & Neyret 2008, Bruneton 2017); `skyview`, skybake's second
// layout, the same three functions on its textures (lut-skyview.glsl appended to it). Also
// evaluates queries into a float framebuffer (`probe`), which tools/browser/lut_test.mjs compares
// with the reference reader and the `sky` product.
"use strict";

class LiveSky {
  /** A renderer on `canvas` (WebGL2) with the shader sources `glsl` (atmosphere.glsl) and
   *  `skyviewGlsl` (skyview.glsl; needed for `skyview` bundles only). */
  constructor(canvas, glsl, skyviewGlsl = null) {
    const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true });
    if (!gl) throw new Error("WebGL2 is not available in this browser");
    this.gl = gl;
    this.canvas = canvas;
    // Linear filtering of the 32-bit float textures (transmittance, irradiance); without it they
    // are uploaded as 16-bit floats, which every WebGL2 device filters.
    this.floatLinear = !!gl.getExtension("OES_texture_float_linear");
    this.floatTarget = !!gl.getExtension("EXT_color_buffer_float");
    this.glsl = glsl;
    this.skyviewGlsl = skyviewGlsl;
    this.vs = `#version 300 es
      in vec2 position; out vec2 frag_uv;
      void main() { frag_uv = position * 0.5 + 0.5; gl_Position = vec4(position, 0.0, 1.0); }`;
    this.programs = {};
    const quad = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, quad);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    this.manifest = null;
  }

  program(vsSource, fsSource) {
    const gl = this.gl;
    const compile = (type, src) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
      return s;
    };
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, vsSource));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fsSource));
    gl.bindAttribLocation(p, 0, "position");
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(p)}`);
    return p;
  }

  /** The programs (panorama and probes) for the loaded bundle's layout, compiled once per layout
   *  and node counts: `skyview` needs its sizes and sun segments as shader constants. */
  programsFor(manifest) {
    let defines = "";
    let source = this.glsl;
    if (manifest.format === "skyview") {
      if (!this.skyviewGlsl) throw new Error("the skyview shader (lut-skyview.glsl) was not given");
      const z = manifest.parameterisation.sizes;
      const segments = manifest.parameterisation.sun_segments;
      defines = "#define SKYVIEW_LAYOUT\n" +
        ["N_ALT", "N_SUN", "N_VIEW_SKY", "N_VIEW_LIMB", "N_VIEW_DOWN", "N_AZ"]
          .map((k) => {
            if (!Number.isInteger(z[k]) || z[k] < 2) throw new Error(`manifest: parameterisation.sizes.${k} is not a node count`);
            return `#define SV_${k} ${z[k]}\n`;
          }).join("") +
        `#define SV_N_SUN_SEGMENTS ${segments.length}\n`;
      const shadowScale = manifest.parameterisation.limb_shadow_scale_m;
      if (!(shadowScale > 0)) throw new Error("manifest: parameterisation.limb_shadow_scale_m is not a length");
      defines += `#define SV_LIMB_SHADOW_SCALE ${shadowScale.toExponential()}\n`;
      const warp = manifest.parameterisation.sun_warp_strength;
      const warpRange = manifest.parameterisation.sun_warp_range;
      if (!(warp >= 0)) throw new Error("manifest: parameterisation.sun_warp_strength is not a strength");
      if (!Array.isArray(warpRange) || warpRange.length !== 2 || !(warpRange[0] < 0 && warpRange[1] > 0)) {
        throw new Error("manifest: parameterisation.sun_warp_range is not a range around 0");
      }
      defines += `#define SV_SUN_WARP ${warp.toExponential()}\n` +
        `#define SV_SUN_WARP_LO ${warpRange[0].toExponential()}\n` +
        `#define SV_SUN_WARP_HI ${warpRange[1].toExponential()}\n`;
      // The sky rows' focus on the band above the earth's shadow (version 4), and the band's
      // elevation with the azimuth (version 5), its fit aloft and the depth's top (version 9), the
      // focus's growth aloft (version 11), the columns' depth aloft (version 12), the focus's fade
      // with the band's elevation (version 13), the focus's place and strength from 6-12 km
      // under a low band, the band's sun term turned smoothly to 0 (version 15), the band's
      // growth aloft in the slices' map (version 16), the focus's width (version 18).
      const band = manifest.parameterisation.sky_row_band;
      const numbers = (v, n) => Array.isArray(v) && v.length === n && v.every(Number.isFinite);
      if (!band || !(band.focus > 0) || !Number.isFinite(band.sun_deg) || !numbers(band.centre, 4) ||
          !numbers(band.sun_range_deg, 4) || !numbers(band.altitude_range_m, 2) ||
          !(band.antisolar > 0) || !(band.depth_deg_per_km >= 0) || !(band.horizon_deg > 0) ||
          !numbers(band.antisolar_range, 2) || !(band.focus_growth >= 0) ||
          !numbers(band.focus_growth_altitude_m, 2) ||
          !(band.focus_growth_altitude_m[0] < band.focus_growth_altitude_m[1]) ||
          !Number.isFinite(band.centre_aloft_per_km) || !numbers(band.centre_aloft_altitude_m, 2) ||
          !(band.centre_aloft_altitude_m[0] <= band.centre_aloft_altitude_m[1]) ||
          !Number.isFinite(band.centre_top_per_km) || !Number.isFinite(band.centre_top_altitude_m) ||
          !numbers(band.slices_aloft_per_km, 2) || !numbers(band.slices_through_altitude_m, 2) ||
          !(band.slices_through_altitude_m[0] < band.slices_through_altitude_m[1]) ||
          !numbers(band.slices_azimuth_altitude_m, 2) || !Number.isFinite(band.slices_top_per_km) ||
          !(band.slices_azimuth_altitude_m[0] < band.slices_azimuth_altitude_m[1]) ||
          !(band.depth_top_m >= 0) || !(band.focus_aloft >= 0) ||
          !numbers(band.focus_aloft_altitude_m, 2) ||
          !(band.focus_aloft_altitude_m[0] < band.focus_aloft_altitude_m[1]) ||
          !(band.focus_place_aloft > 0) || !numbers(band.focus_place_altitude_m, 2) ||
          !(band.focus_place_altitude_m[0] < band.focus_place_altitude_m[1]) ||
          !(band.focus_high >= 0) || !(band.sun_soft_deg > 0) ||
          !(band.focus_width_azimuth_cos >= 0) || !(band.focus_width_floor_deg >= 0) ||
          !numbers(band.focus_width_altitude_m, 4) ||
          !(band.focus_width_altitude_m[0] < band.focus_width_altitude_m[1]) ||
          !(band.focus_width_altitude_m[2] < band.focus_width_altitude_m[3]) ||
          !(band.focus_wide >= 0) ||
          !(band.azimuth_depth_aloft_deg >= 0) || !numbers(band.azimuth_depth_aloft_altitude_m, 2) ||
          !(band.azimuth_depth_aloft_altitude_m[0] < band.azimuth_depth_aloft_altitude_m[1]) ||
          !numbers(band.centre_range_deg, 2) || !(band.centre_range_deg[0] < band.centre_range_deg[1]) ||
          !(band.centre_floor >= 0 && band.centre_floor <= 1)) {
        throw new Error("manifest: parameterisation.sky_row_band is not the sky rows' band focus");
      }
      // The altitude nodes, where each slice's own rows are read (version 6).
      const altNodes = manifest.parameterisation.altitude_nodes_m;
      if (!numbers(altNodes, z.N_ALT)) {
        throw new Error("manifest: parameterisation.altitude_nodes_m is not N_ALT altitudes");
      }
      const altX = manifest.parameterisation.altitude_node_abscissas;
      if (!numbers(altX, z.N_ALT) || !altX.every((x, k) => k === 0 || x > altX[k - 1])) {
        throw new Error("manifest: parameterisation.altitude_node_abscissas is not N_ALT increasing abscissas");
      }
      const f = (x) => x.toExponential();
      defines += `#define SV_BAND_SUN ${f(band.sun_deg)}\n` +
        `#define SV_BAND_FOCUS ${f(band.focus)}\n` +
        `#define SV_BAND_CENTRE vec4(${band.centre.map(f).join(", ")})\n` +
        `#define SV_BAND_SUN_RANGE vec4(${band.sun_range_deg.map(f).join(", ")})\n` +
        `#define SV_BAND_ALTITUDE vec2(${band.altitude_range_m.map(f).join(", ")})\n` +
        `#define SV_BAND_CENTRE_RANGE vec2(${band.centre_range_deg.map(f).join(", ")})\n` +
        `#define SV_BAND_CENTRE_FLOOR ${f(band.centre_floor)}\n` +
        `#define SV_BAND_ANTISOLAR ${f(band.antisolar)}\n` +
        `#define SV_BAND_DEPTH ${f(band.depth_deg_per_km)}\n` +
        `#define SV_BAND_HORIZON ${f(band.horizon_deg)}\n` +
        `#define SV_BAND_ANTISOLAR_RANGE vec2(${band.antisolar_range.map(f).join(", ")})\n` +
        `#define SV_BAND_GROWTH ${f(band.focus_growth)}\n` +
        `#define SV_BAND_GROWTH_ALTITUDE vec2(${band.focus_growth_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_CENTRE_ALOFT ${f(band.centre_aloft_per_km)}\n` +
        `#define SV_BAND_CENTRE_ALOFT_ALTITUDE vec2(${band.centre_aloft_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_CENTRE_TOP vec2(${f(band.centre_top_altitude_m)}, ${f(band.centre_top_per_km)})\n` +
        `#define SV_BAND_SLICE_ALOFT vec2(${band.slices_aloft_per_km.map(f).join(", ")})\n` +
        `#define SV_BAND_SLICE_THROUGH vec2(${band.slices_through_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_SLICE_TOP ${f(band.slices_top_per_km)}\n` +
        `#define SV_BAND_SLICE_AZIMUTH vec2(${band.slices_azimuth_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_DEPTH_TOP ${f(band.depth_top_m)}\n` +
        `#define SV_BAND_FOCUS_ALOFT ${f(band.focus_aloft)}\n` +
        `#define SV_BAND_FOCUS_ALOFT_ALTITUDE vec2(${band.focus_aloft_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_FOCUS_PLACE_ALOFT ${f(band.focus_place_aloft)}\n` +
        `#define SV_BAND_FOCUS_PLACE_ALTITUDE vec2(${band.focus_place_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_FOCUS_HIGH ${f(band.focus_high)}\n` +
        `#define SV_BAND_FOCUS_WIDTH_AZIMUTH ${f(band.focus_width_azimuth_cos)}\n` +
        `#define SV_BAND_FOCUS_WIDTH_FLOOR ${f(band.focus_width_floor_deg)}\n` +
        `#define SV_BAND_FOCUS_WIDTH_ALTITUDE vec4(${band.focus_width_altitude_m.map(f).join(", ")})\n` +
        `#define SV_BAND_FOCUS_WIDE ${f(band.focus_wide)}\n` +
        `#define SV_BAND_SUN_SOFT ${f(band.sun_soft_deg)}\n` +
        `#define SV_BAND_AZIMUTH_DEPTH_ALOFT ${f(band.azimuth_depth_aloft_deg)}\n` +
        `#define SV_BAND_AZIMUTH_DEPTH_ALTITUDE vec2(${band.azimuth_depth_aloft_altitude_m.map(f).join(", ")})\n` +
        `#define SV_ALT_NODES float[${z.N_ALT}](${altNodes.map(f).join(", ")})\n` +
        `#define SV_ALT_X float[${z.N_ALT}](${altX.map(f).join(", ")})\n`;
      // The limb's sun coordinate back towards the observer's horizon aloft away from the sun
      // (version 11).
      const nearEnd = manifest.parameterisation.limb_near_end;
      if (!nearEnd || !numbers(nearEnd.azimuth_cos, 2) || !numbers(nearEnd.depth_m, 2) ||
          !numbers(nearEnd.altitude_range_m, 2) || !(nearEnd.azimuth_cos[0] < nearEnd.azimuth_cos[1]) ||
          !(nearEnd.depth_m[0] < nearEnd.depth_m[1]) ||
          !(nearEnd.altitude_range_m[0] < nearEnd.altitude_range_m[1]) ||
          !numbers(nearEnd.node_query_weight_altitude_m, 2) ||
          !(nearEnd.node_query_weight_altitude_m[0] < nearEnd.node_query_weight_altitude_m[1])) {
        throw new Error("manifest: parameterisation.limb_near_end is not the limb's near-end weight");
      }
      defines += `#define SV_LIMB_NEAR_END_AZIMUTH vec2(${nearEnd.azimuth_cos.map(f).join(", ")})\n` +
        `#define SV_LIMB_NEAR_END_DEPTH vec2(${nearEnd.depth_m.map(f).join(", ")})\n` +
        `#define SV_LIMB_NEAR_END_ALTITUDE vec2(${nearEnd.altitude_range_m.map(f).join(", ")})\n` +
        `#define SV_LIMB_NODE_QUERY_WEIGHT vec2(${nearEnd.node_query_weight_altitude_m.map(f).join(", ")})\n`;
      // The altitudes over which the limb's altitude nodes go from the query's exponential to
      // their own tangent-point weight (the reader's limb_node_shift).
      const nodeWeight = nearEnd.node_weight_altitude_m;
      if (!numbers(nodeWeight, 2) || !(nodeWeight[0] < nodeWeight[1])) {
        throw new Error("manifest: parameterisation.limb_near_end.node_weight_altitude_m is not an altitude range");
      }
      defines += `#define SV_LIMB_NODE_WEIGHT_ALTITUDE vec2(${nodeWeight.map(f).join(", ")})\n`;
      // The limb rows' focus on the band above the earth's shadow seen from altitude (version 10;
      // the slices' two-piece depth map, version 11).
      const limb = manifest.parameterisation.limb_row_band;
      if (!limb || !(limb.focus > 0) || !numbers(limb.depth_m, 3) || !numbers(limb.sun_range_deg, 4) ||
          !numbers(limb.altitude_range_m, 4) || !(limb.depth_floor_m > 0) ||
          !Number.isFinite(limb.altitude_exponent) ||
          !(limb.max_fraction > 0 && limb.max_fraction < 1) || !numbers(limb.horizon_held, 2) ||
          !(limb.horizon_held[0] < limb.horizon_held[1]) ||
          !(limb.deepest > 0 && limb.deepest <= 1) || !numbers(limb.edge_depth_m, 2) ||
          !(limb.edge_focus >= 0) || !numbers(limb.edge_sun_range_deg, 4) ||
          !numbers(limb.edge_altitude_range_m, 4)) {
        throw new Error("manifest: parameterisation.limb_row_band is not the limb rows' band focus");
      }
      defines += `#define SV_LIMB_BAND_DEPTH vec3(${limb.depth_m.map(f).join(", ")})\n` +
        `#define SV_LIMB_BAND_FOCUS ${f(limb.focus)}\n` +
        `#define SV_LIMB_BAND_SUN_RANGE vec4(${limb.sun_range_deg.map(f).join(", ")})\n` +
        `#define SV_LIMB_BAND_ALTITUDE vec4(${limb.altitude_range_m.map(f).join(", ")})\n` +
        `#define SV_LIMB_BAND_DEPTH_FLOOR ${f(limb.depth_floor_m)}\n` +
        `#define SV_LIMB_BAND_ALTITUDE_EXPONENT ${f(limb.altitude_exponent)}\n` +
        `#define SV_LIMB_BAND_MAX_FRACTION ${f(limb.max_fraction)}\n` +
        `#define SV_LIMB_BAND_HORIZON_HELD vec2(${limb.horizon_held.map(f).join(", ")})\n` +
        `#define SV_LIMB_BAND_DEEPEST ${f(limb.deepest)}\n` +
        `#define SV_LIMB_EDGE_DEPTH vec2(${limb.edge_depth_m.map(f).join(", ")})\n` +
        `#define SV_LIMB_EDGE_FOCUS ${f(limb.edge_focus)}\n` +
        `#define SV_LIMB_EDGE_SUN_RANGE vec4(${limb.edge_sun_range_deg.map(f).join(", ")})\n` +
        `#define SV_LIMB_EDGE_ALTITUDE vec4(${limb.edge_altitude_range_m.map(f).join(", ")})\n`;
      // The azimuth columns' map aloft (version 5).
      const az = manifest.parameterisation.azimuth_aloft;
      if (!az || !(az.weight > 0 && az.weight <= 1) || !(az.ground_weight > 0 && az.ground_weight <= 1) ||
          !numbers(az.altitude_range_m, 2) ||
          !(az.altitude_range_m[0] < az.altitude_range_m[1])) {
        throw new Error("manifest: parameterisation.azimuth_aloft is not the columns' map aloft");
      }
      // The columns' focus aloft and every altitude node's column azimuths (version 13: each
      // altitude node's columns read in its own map).
      const azFocus = manifest.parameterisation.azimuth_focus;
      if (!azFocus || !(azFocus.weight >= 0 && azFocus.weight < 1) || !(azFocus.width_deg > 0) ||
          !Number.isFinite(azFocus.centre_deg) || !numbers(azFocus.altitude_range_m, 2) ||
          !(azFocus.altitude_range_m[0] < azFocus.altitude_range_m[1]) ||
          !numbers(azFocus.node_read_altitude_m, 2) ||
          !(azFocus.node_read_altitude_m[0] < azFocus.node_read_altitude_m[1])) {
        throw new Error("manifest: parameterisation.azimuth_focus is not the columns' focus aloft");
      }
      const azNodes = manifest.parameterisation.azimuth_nodes_rad;
      if (!Array.isArray(azNodes) || azNodes.length !== z.N_ALT || !azNodes.every((v) => numbers(v, z.N_AZ))) {
        throw new Error("manifest: parameterisation.azimuth_nodes_rad is not N_ALT x N_AZ azimuths");
      }
      // The altitude nodes' map (version 5).
      const altMap = manifest.parameterisation.altitude_map;
      if (!numbers(altMap, 3) || !(altMap[1] > altMap[2] && altMap[2] > 0)) {
        throw new Error("manifest: parameterisation.altitude_map is not [c, p, q]");
      }
      // The sky rows' sun coordinate aloft (version 9).
      const exit = manifest.parameterisation.sky_exit_altitude_m;
      if (!numbers(exit, 2) || !(exit[0] < exit[1])) {
        throw new Error("manifest: parameterisation.sky_exit_altitude_m is not an altitude range");
      }
      defines += `#define SV_SKY_EXIT_ALTITUDE vec2(${exit.map(f).join(", ")})\n`;
      // Its azimuth weight's fade away from the sun (after layout version 20).
      const exitFade = manifest.parameterisation.sky_exit_azimuth_fade;
      if (!Number.isFinite(exitFade) || !(exitFade > 0 && exitFade <= 1)) {
        throw new Error("manifest: parameterisation.sky_exit_azimuth_fade is not a cosine in (0, 1]");
      }
      defines += `#define SV_SKY_EXIT_AZIMUTH_FADE ${f(exitFade)}\n`;
      // The twilight warp's centre on the sky rows towards the sun aloft (version 15).
      const centre = manifest.parameterisation.sun_warp_centre;
      if (!centre || !Number.isFinite(centre.weight) || !numbers(centre.altitude_range_m, 2) ||
          !(centre.altitude_range_m[0] < centre.altitude_range_m[1])) {
        throw new Error("manifest: parameterisation.sun_warp_centre is not a weight and an altitude range");
      }
      defines += `#define SV_SUN_WARP_CENTRE ${f(centre.weight)}\n` +
        `#define SV_SUN_WARP_CENTRE_ALTITUDE vec2(${centre.altitude_range_m.map(f).join(", ")})\n`;
      defines += `#define SV_ALT_MAP vec3(${altMap.map(f).join(", ")})\n` +
        `#define SV_AZ_WEIGHT ${f(az.weight)}\n` +
        `#define SV_AZ_GROUND_WEIGHT ${f(az.ground_weight)}\n` +
        `#define SV_AZ_ALTITUDE vec2(${az.altitude_range_m.map(f).join(", ")})\n` +
        `#define SV_AZ_FOCUS vec3(${[azFocus.weight, azFocus.centre_deg, azFocus.width_deg].map(f).join(", ")})\n` +
        `#define SV_AZ_FOCUS_ALTITUDE vec2(${azFocus.altitude_range_m.map(f).join(", ")})\n` +
        `#define SV_AZ_NODE_READ vec2(${azFocus.node_read_altitude_m.map(f).join(", ")})\n` +
        `#define SV_AZ_NODE_COS float[${z.N_ALT * z.N_AZ}](${azNodes.flat().map((x) => f(Math.cos(x))).join(", ")})\n`;
      source = `${this.glsl}\n${this.skyviewGlsl}`;
    }
    if (!this.programs[defines]) {
      this.programs[defines] = {
        sky: this.program(this.vs, `#version 300 es\n#define SKY_VIEW\n${defines}${source}`),
        probe: this.program(this.vs, `#version 300 es\n#define PROBES\n${defines}${source}`),
      };
    }
    return this.programs[defines];
  }

  /** Fetches the manifest at `manifestUrl` and its textures (once each), and uploads them. Reads
   *  the two layouts: `bruneton2017` in its RGB (combined) form, and `skyview` (RGB). */
  async load(manifestUrl, fetchOk = fetch) {
    const manifest = await fetchOk(manifestUrl).then((r) => r.json());
    let names;
    if (manifest.format === "bruneton2017" && manifest.parameterisation.combined_scattering_textures) {
      names = ["transmittance", "scattering", "irradiance"];
    } else if (manifest.format === "skyview" && manifest.channels.length === 3) {
      names = ["transmittance", "rayleigh", "mie", "scale", "irradiance"];
    } else {
      throw new Error("the live sky reads RGB bundles: Bruneton 2017's combined layout or skyview");
    }
    const files = await Promise.all(names.map(async (name) => {
      const t = manifest.textures[name];
      const href = manifest.links[t.file];
      const exr = await decodeExr(await fetchOk(href).then((r) => r.arrayBuffer()));
      if (exr.width !== t.width || exr.height !== t.height * t.depth) {
        throw new Error(`${t.file}: ${exr.width}×${exr.height}, manifest ${t.width}×${t.height * t.depth}`);
      }
      return [name, { t, exr }];
    }));
    const programs = this.programsFor(manifest);
    const gl = this.gl;
    for (const tex of Object.values(this.textures || {})) gl.deleteTexture(tex);
    const f = Object.fromEntries(files);
    if (manifest.format === "skyview") {
      const split = (prefix) => ({ ...f.scale.t, channels: f.scale.t.channels.filter((c) => c.startsWith(prefix)) });
      this.textures = {
        transmittance_texture: this.texture2d(f.transmittance.t, f.transmittance.exr),
        skyview_rayleigh: this.skyviewTiles(manifest, f.rayleigh.t, f.rayleigh.exr),
        skyview_mie: this.skyviewTiles(manifest, f.mie.t, f.mie.exr),
        skyview_scale_rayleigh: this.texture2d(split("rayleigh."), f.scale.exr, true),
        skyview_scale_mie: this.texture2d(split("mie."), f.scale.exr, true),
        skyview_irradiance: this.texture2d(f.irradiance.t, f.irradiance.exr, true),
      };
    } else {
      this.textures = {
        transmittance_texture: this.texture2d(f.transmittance.t, f.transmittance.exr),
        scattering_texture: this.texture3d(f.scattering.t, f.scattering.exr),
        irradiance_texture: this.texture2d(f.irradiance.t, f.irradiance.exr),
      };
    }
    this.skyProgram = programs.sky;
    this.probeProgram = programs.probe;
    this.manifest = manifest;
    return manifest;
  }

  /** A skyview texture (rayleigh or mie: N_AZ × N_VIEW per slice, slice = altitude · N_SUN + sun,
   *  stacked in the file) as one 2-D RGBA16F texture with the slice of (altitude k, sun j) at
   *  columns j·N_AZ… and rows k·N_VIEW… (every WebGL2 device holds 2048² 2-D textures; a 3-D
   *  texture of 2100 slices exceeds the guaranteed 256). Read by texelFetch: exact half floats. */
  skyviewTiles(manifest, t, exr) {
    const gl = this.gl;
    const z = manifest.parameterisation.sizes;
    const nView = z.N_VIEW_SKY + z.N_VIEW_LIMB + z.N_VIEW_DOWN;
    if (t.width !== z.N_AZ || t.height !== nView || t.depth !== z.N_ALT * z.N_SUN || t.sample !== "half") {
      throw new Error(`${t.file}: not ${z.N_AZ}×${nView}×${z.N_ALT * z.N_SUN} half floats`);
    }
    const src = this.interleave(t, exr, true);
    const width = z.N_AZ * z.N_SUN;
    const height = nView * z.N_ALT;
    const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    if (width > max || height > max) throw new Error(`${t.file}: ${width}×${height} exceeds this device's ${max}`);
    const out = new Uint16Array(4 * width * height);
    const rowTexels = z.N_AZ * 4;
    for (let k = 0; k < z.N_ALT; k++) {
      for (let j = 0; j < z.N_SUN; j++) {
        for (let i = 0; i < nView; i++) {
          const from = (((k * z.N_SUN + j) * nView + i) * z.N_AZ) * 4;
          const to = ((k * nView + i) * width + j * z.N_AZ) * 4;
          out.set(src.subarray(from, from + rowTexels), to);
        }
      }
    }
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, width, height, 0, gl.RGBA, gl.HALF_FLOAT, out);
    this.filtering(gl.TEXTURE_2D, true);
    return tex;
  }

  /** RGBA texel array of `exr`'s channels in the manifest's order (missing channels 0, A 1). */
  interleave(t, exr, half) {
    const n = exr.width * exr.height;
    const out = half ? new Uint16Array(4 * n) : new Float32Array(4 * n);
    const names = t.channels;
    for (let c = 0; c < 4; c++) {
      const src = names[c] !== undefined ? (half ? exr.halfBits[names[c]] : exr.channels[names[c]]) : null;
      if (names[c] !== undefined && !src) throw new Error(`${t.file}: no ${half ? "half " : ""}channel ${names[c]}`);
      for (let i = 0; i < n; i++) out[4 * i + c] = src ? src[i] : (half ? 0x3c00 : 1);
    }
    return out;
  }

  /** Texture parameters and the (format, type, data) a file uploads as; `fetched`: read by
   *  texelFetch only (32-bit floats need no filtering extension then). */
  upload(t, exr, fetched = false) {
    const gl = this.gl;
    if (t.sample === "half") return [gl.RGBA16F, gl.HALF_FLOAT, this.interleave(t, exr, true)];
    if (this.floatLinear || fetched) return [gl.RGBA32F, gl.FLOAT, this.interleave(t, exr, false)];
    return [gl.RGBA16F, gl.FLOAT, this.interleave(t, exr, false)];
  }

  filtering(target, nearest = false) {
    const gl = this.gl;
    gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, nearest ? gl.NEAREST : gl.LINEAR);
    gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, nearest ? gl.NEAREST : gl.LINEAR);
    gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.texParameteri(target, gl.TEXTURE_WRAP_R, gl.CLAMP_TO_EDGE);
  }

  /** A 2-D texture; `fetched`: read by texelFetch (nearest filtering, 32-bit floats kept). */
  texture2d(t, exr, fetched = false) {
    const gl = this.gl;
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    const [format, type, data] = this.upload(t, exr, fetched);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.texImage2D(gl.TEXTURE_2D, 0, format, t.width, t.height, 0, gl.RGBA, type, data);
    this.filtering(gl.TEXTURE_2D, fetched);
    return tex;
  }

  /** The 3-D scattering texture: the file's stacked r slices are its depth slices, in order. */
  texture3d(t, exr) {
    const gl = this.gl;
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_3D, tex);
    const [format, type, data] = this.upload(t, exr);
    gl.texImage3D(gl.TEXTURE_3D, 0, format, t.width, t.height, t.depth, 0, gl.RGBA, type, data);
    this.filtering(gl.TEXTURE_3D);
    return tex;
  }

  /** Binds the bundle's textures and his AtmosphereParameters (from the manifest) to `p`; for
   *  `skyview`, also the sun segments and the aerosol's phase function. */
  bindBundle(p) {
    const gl = this.gl;
    const m = this.manifest;
    const a = m.atmosphere_parameters;
    gl.useProgram(p);
    Object.entries(this.textures).forEach(([name, tex], i) => {
      gl.activeTexture(gl.TEXTURE0 + i);
      gl.bindTexture(name === "scattering_texture" ? gl.TEXTURE_3D : gl.TEXTURE_2D, tex);
      gl.uniform1i(gl.getUniformLocation(p, name), i);
    });
    for (const k of ["bottom_radius", "top_radius", "mu_s_min", "sun_angular_radius", "mie_phase_function_g"]) {
      gl.uniform1f(gl.getUniformLocation(p, k), a[k]);
    }
    for (const k of ["solar_irradiance", "rayleigh_scattering", "mie_scattering"]) {
      gl.uniform3fv(gl.getUniformLocation(p, k), a[k]);
    }
    if (m.format === "skyview") {
      gl.uniform3fv(gl.getUniformLocation(p, "skyview_sun_segments"), m.parameterisation.sun_segments.flat());
      const phase = m.aerosol_phase_function;
      const kinds = ["cornette_shanks", "henyey_greenstein", "mixture", "isotropic", "rayleigh"];
      const kind = kinds.indexOf(phase.kind);
      if (kind < 0) throw new Error(`manifest: unknown aerosol_phase_function ${phase.kind}`);
      gl.uniform1i(gl.getUniformLocation(p, "aerosol_phase_kind"), kind);
      gl.uniform1f(gl.getUniformLocation(p, "aerosol_g"), phase.g || 0);
      gl.uniform1f(gl.getUniformLocation(p, "aerosol_rayleigh_fraction"), phase.rayleigh_fraction || 0);
    }
  }

  /** Sun direction for elevation `deg` (x towards the sun's azimuth, z up at the camera). */
  static sunDirection(deg) {
    const e = (deg * Math.PI) / 180;
    return [Math.cos(e), 0, Math.sin(e)];
  }

  /** Draws the panorama: observer `altitudeM` above the ground, sun at `sunElevationDeg`,
   *  display value 1 − exp(−L · exposure), L in mW m⁻² sr⁻¹ nm⁻¹. */
  render({ sunElevationDeg, altitudeM, exposure }) {
    if (!this.manifest) return;
    const gl = this.gl;
    const p = this.skyProgram;
    this.bindBundle(p);
    const a = this.manifest.atmosphere_parameters;
    const u = (name) => gl.getUniformLocation(p, name);
    gl.uniform3fv(u("camera"), [0, 0, a.bottom_radius + Math.max(altitudeM, 1)]);
    gl.uniform3fv(u("sun_direction"), LiveSky.sunDirection(sunElevationDeg));
    gl.uniform3fv(u("ground_albedo"), a.ground_albedo);
    gl.uniform1f(u("exposure"), exposure);
    gl.uniform2f(u("view_size"), this.canvas.width, this.canvas.height);
    gl.uniform2f(u("elevation_range"), (-30 * Math.PI) / 180, (60 * Math.PI) / 180);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
  }

  /** Evaluates queries ({function, camera|point, view|point|normal, sun}, as `skybake lut-eval`
   *  takes them) on the GPU into a float framebuffer; returns [{first, second}] per query
   *  (radiance and transmittance, or sun and sky irradiance), in the bundle's unit. */
  probe(queries) {
    if (!this.manifest) throw new Error("no bundle loaded");
    if (!this.floatTarget) throw new Error("EXT_color_buffer_float is not available: float read-back impossible");
    const gl = this.gl;
    const n = queries.length;
    const ids = { sky_radiance: 0, sky_radiance_to_point: 1, sun_and_sky_irradiance: 2 };
    const data = new Float32Array(n * 3 * 4);
    queries.forEach((q, i) => {
      const id = ids[q.function];
      if (id === undefined) throw new Error(`query ${i}: unknown function ${q.function}`);
      // The aerial query's point goes in as its offset from the camera (computed here in doubles).
      const [p0, p1] = id === 0 ? [q.camera, q.view]
        : id === 1 ? [q.camera, q.point.map((x, k) => x - q.camera[k])] : [q.point, q.normal];
      data.set([...p0, id], 4 * i);
      data.set([...p1, 0], 4 * (n + i));
      data.set([...q.sun, 0], 4 * (2 * n + i));
    });
    const p = this.probeProgram;
    this.bindBundle(p);
    const qtex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE8);
    gl.bindTexture(gl.TEXTURE_2D, qtex);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, n, 3, 0, gl.RGBA, gl.FLOAT, data);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.uniform1i(gl.getUniformLocation(p, "queries"), 8);
    const target = gl.createTexture();
    gl.activeTexture(gl.TEXTURE9);
    gl.bindTexture(gl.TEXTURE_2D, target);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, n, 1, 0, gl.RGBA, gl.FLOAT, null);
    const fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
    if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error("float framebuffer incomplete");
    gl.viewport(0, 0, n, 1);
    gl.bindVertexArray(this.vao);
    const out = queries.map(() => ({}));
    for (const [which, key] of [[0, "first"], [1, "second"]]) {
      gl.uniform1i(gl.getUniformLocation(p, "probe_output"), which);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
      const px = new Float32Array(4 * n);
      gl.readPixels(0, 0, n, 1, gl.RGBA, gl.FLOAT, px);
      out.forEach((o, i) => { o[key] = [px[4 * i], px[4 * i + 1], px[4 * i + 2]]; });
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.deleteFramebuffer(fb);
    gl.deleteTexture(target);
    gl.deleteTexture(qtex);
    return out;
  }
}
