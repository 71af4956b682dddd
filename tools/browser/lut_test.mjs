// Browser test of the viewer's live sky (web/lut/: the WebGL2 client of the texture bundle,
// docs/lut.md), for both layouts: `skyview` (the viewer's default, web/lut/skyview.glsl) and
// Bruneton 2017's (web/lut/atmosphere.glsl). Starts `skybake serve`, opens `/` in Debian's headless
// Chromium (software WebGL), and for each layout loads the bundle through the page (GET /v1/lut,
// once), moves the live sliders and checks that the picture changes without a request. Then it
// evaluates known queries with the page's shader into a float framebuffer
// (EXT_color_buffer_float), reads them back, and compares them
//   (a) with the reference reader's evaluation of the same bundle files (`skybake lut-eval`, the
//       Rust reader of the layout: crates/lut/src/skyview.rs or crates/lut/src/reader.rs):
//       checks the shader;
//   (b) with the `sky` product at the same directions (GET /v1/sky?probe=…, method precise, the
//       same atmosphere, albedo and quality): the layout's own error, per band. `skyview`: the
//       issue's 1 / 3 % targets asserted where the layout meets them (by day, at the ground and
//       0-20 km), the measured bounds elsewhere; Bruneton's: the measured bounds (his 4-D layout
//       meets no target, docs/lut.md). Every figure is printed.
// Every expected value comes from skybake's Rust code through the CLI or the running service.
//
// Usage: node tools/browser/lut_test.mjs [path/to/skybake] [screenshot dir]
import { execFileSync } from "node:child_process";
import { mkdirSync, mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, dirname, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { chromium } from "playwright-core";
import { startServer } from "./serve.mjs";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..", "..");
const binary = resolve(process.argv[2] || join(root, "target", "release", "skybake"));
const chromePath = process.env.CHROMIUM || "/usr/bin/chromium";
const shots = process.argv[3] ? resolve(process.argv[3]) : null;
if (shots) mkdirSync(shots, { recursive: true });

// The bundle and the products compared with it.
const ATMOSPHERE = "earth";
const ALBEDO = "0.1";
// The viewer's default quality (and the service's): the comparisons (b) then measure the layouts
// against the sky product a user gets by default. At `draft` the sky product itself is up to 22 %
// off in deep twilight (its stated error there is 17 %): at 5 km, sun -11 deg, 5 deg above the
// horizon towards the sun the draft `skyview` bundle reads 5.4 % from the standard sky product
// but 20.7 % from the draft one, which was this test's figure until 2026-12-06.
const QUALITY = "standard";

// (a) shader vs reader: largest deviation relative to the reader's value (radiance, irradiance;
// for GetSkyRadianceToPoint relative to the whole ray's in-scatter, as it is a difference of two
// lookups) or absolute (transmittance). Measured (software WebGL), Bruneton's layout:
// GetSkyRadiance 8.9e-6, GetSkyRadianceToPoint 1.2e-3 (camera 1 m above the ground; 3.5e-4 from
// 2-10 km), GetSunAndSkyIrradiance 1.4e-6; transmittances 1.8e-5 absolute. skyview: SKYVIEW_SHADER.
const SHADER_BOUND = { relative: 2e-3, transmittance: 1e-4 };
// (b) shader vs the sky product, largest relative error per band over R, G, B (680, 550, 440 nm).
// Bounds: measured on this bundle (earth, albedo 0.1, standard; 2026-12-06, the reader on these
// cases: 16.95 / 21.90 / 21.08 / 66.30 / 61.83 %) × 1.15; targets from the issue.
const BRUNETON_BANDS = [
  { name: "ground, sun >= 5 deg, view > 10 deg above the horizon", target: 0.01, bound: 0.195,
    cases: cross([0], [10, 30, 60], [0, 30, 60, 75], [0, 90, 180]) },
  { name: "ground, sun >= 5 deg, view < 10 deg above the horizon", target: 0.03, bound: 0.252,
    cases: cross([0], [10, 30, 60], [82, 87, 89.5], [0, 90, 180]) },
  { name: "0-20 km, sun >= 5 deg", target: 0.01, bound: 0.243,
    cases: cross([2000, 10000], [10, 40], [0, 45, 75, 88], [0, 90, 180]) },
  { name: "0-5 km, sun -6..5 deg, view < 10 deg above the horizon", target: 0.03, bound: 0.763,
    cases: cross([0, 5000], [2, -3], [82, 87], [0, 90, 180]) },
  { name: "0-5 km, sun -12..-6 deg", target: 0.10, bound: 0.711,
    cases: cross([0, 5000], [-8, -11], [0, 60, 85], [0, 180]) },
];

// skyview (the viewer's default): `assert: "target"` asserts the target; every band meets
// it at `standard` (layout version 11, 2026-12-06, the reader on these cases: 0.47 / 0.75 / 0.39 /
// 0.56 / 0.06 / 0.41 / 0.57 %, -12..-6 deg 6.13 % (5 km, sun -11 deg, 5 deg above the horizon
// towards the sun, R; at `draft` 20.7 %, the draft sky product's own error), the band above the
// earth's shadow 2.79 % (G, 12.5 km, sun -3 deg, zenith 88 deg, 120 deg from the sun), below the
// horizontal 2.34 % (R, 12.5 km, sun -3 deg, zenith 93.25 deg, 150 deg)).
const SKYVIEW_BANDS = [
  { name: "ground, sun >= 5 deg, view > 10 deg above the horizon", target: 0.01, assert: "target",
    cases: cross([0], [10, 30, 60], [0, 30, 60, 75], [0, 90, 180]) },
  { name: "ground, sun >= 5 deg, view < 10 deg above the horizon", target: 0.03, assert: "target",
    cases: cross([0], [10, 30, 60], [82, 87, 89.5], [0, 90, 180]) },
  { name: "0-20 km, sun >= 5 deg, view > 10 deg above the horizon", target: 0.01, assert: "target",
    cases: cross([2000, 10000, 18000], [10, 40], [0, 45, 75], [0, 90, 180]) },
  { name: "0-20 km, sun >= 5 deg, view < 10 deg above the horizon", target: 0.03, assert: "target",
    cases: cross([2000, 10000, 18000], [10, 40], [84, 88, 91], [0, 90, 180]) },
  { name: "ground and 2 km, sun >= 5 deg, aureole (2-8 deg from the sun)", target: 0.01, assert: "target",
    cases: aureole([0, 2000], [10, 30], [2, 4, 6]) },
  { name: "20-100 km, sun >= 5 deg (zenith 95 deg: the limb)", target: 0.01, assert: "target",
    cases: cross([30000, 60000], [10, 40], [0, 60, 85, 95], [0, 180]) },
  { name: "0-5 km, sun -6..5 deg, view < 10 deg above the horizon", target: 0.03, assert: "target",
    cases: cross([0, 5000], [2, -3], [82, 87], [0, 90, 180]) },
  { name: "0-5 km, sun -12..-6 deg", target: 0.10, assert: "target",
    cases: cross([0, 5000], [-8, -11], [0, 60, 85], [0, 180]) },
  // The band above the earth's shadow seen aloft (layout version 9: the sky rows' focus up to
  // 20 km, the columns aloft read at the query's altitude's azimuths in SkyViewBandRows).
  { name: "8-20 km, sun -5..-1 deg, the band above the earth's shadow", target: 0.03, assert: "target",
    cases: cross([8000, 12500, 17000], [-1, -3, -5], [84, 86, 88], [120, 150, 180]) },
  // The band above the earth's shadow seen from 20-40 km, 30-180 deg from the sun, where the
  // band's maps fade in with the azimuth aloft (SkyViewBandSlice's cos_phi, SkyViewBandRows).
  // Layout version 20 (2026-12-07): shader = reader 7.9e-6 / 3.5e-6; against the sky product
  // 16.92 % at 20-30 km and 34.63 % at 40 km, both at sun -6 deg, zenith 89 deg, 90 deg from the
  // sun (the Rust checks aloft looked 120-180 deg from the sun). Layout version 21 (the sky rows'
  // exit shift faded out over 90-120 deg from the sun, SkyViewExitAzimuth; now also checked in
  // Rust, lut_skyview::skyview_the_sky_beside_the_sun_aloft): 5.63 % at 20-30 km (30 km, sun
  // -4.5 deg, zenith 89 deg, 30 deg from the sun) and 19.13 % at 40 km (sun -6 deg, zenith 89 deg,
  // 90 deg from the sun): the target not met. Bounds: the measured x ~1.15.
  { name: "20-30 km, sun -6..-3 deg, the band above the earth's shadow 30-180 deg from the sun", target: 0.03,
    bound: 0.065,
    cases: cross([20000, 25000, 30000], [-3, -4.5, -6], [84, 86, 87.5, 89], [30, 90, 135, 180]) },
  { name: "40 km, sun -6..-3 deg, the sky just above the horizontal 30-180 deg from the sun", target: 0.03,
    bound: 0.22,
    cases: cross([40000], [-3, -4.5, -6], [84, 86, 87.5, 89], [30, 90, 135, 180]) },
  // Below the horizontal (layout version 10: the limb rows' focus on the band and each slice read
  // at the query's depth relative to it, SkyViewLimbFocus, SkyViewLimbSliceDepth).
  { name: "12.5-20 km, sun -5..-3 deg, the band below the horizontal", target: 0.03, assert: "target",
    cases: cross([12500, 17000, 20000], [-3, -4, -5], [91.5, 92.5, 93.25], [150, 180]) },
  // Aloft in deep twilight towards the sun (layout version 15: the sun warp centred on the
  // terminator's kink from 40-60 km up, SkyViewSunWarpCentre).
  { name: "45-55 km, sun -11..-8 deg, towards the sun", target: 0.10, assert: "target",
    cases: cross([45000, 55000], [-8, -11], [20, 60, 85], [0, 45]) },
];
// (a) for skyview, per band (every sky query grouped by its band): the skyview shader fetches
// texels and interpolates in 32-bit floats as the reader does in 64. Layout version 10
// (2026-12-06, software WebGL): GetSkyRadiance within 5.5e-6 relative in every band,
// GetSkyRadianceToPoint 1.21e-5 / 3.6e-6 of the ray's in-scatter (camera 1 m / 2-10 km),
// GetSunAndSkyIrradiance 8e-7 (sun) / 1e-6 (sky); transmittances 1.8e-5 absolute. Before,
// 1.40e-3 below the horizontal aloft (20 km, sun -4 deg, zenith 93.25 deg, 150 deg from the sun,
// R) and 4.49e-4 above it (8-20 km): SwiftShader's sin and cos err by up to 1.9e-4, its acos by
// 6.7e-5 and its asinh by 5e-5 (at -18), where the limb rows' coordinate (ln L changes 27 per
// unit of it), the sky rows' focus, gamma cos(phi) in the sun coordinate and the azimuth column
// need 1e-6; skyview.glsl now uses its own (SkyViewSinCos, SkyViewAcos, SkyViewAsinh; found by
// tools/browser/skyview_trace.mjs, the reader's and the shader's intermediate quantities side by
// side). Bound: 2e-5 (the largest, 1.21e-5, + margin): new code in skyview.glsl must use those
// functions, not the built-ins.
const SKYVIEW_SHADER_BOUND = { relative: 2e-5, transmittance: 1e-4 };

const LAYOUTS = [
  { layout: "skyview", textures: 5, bands: SKYVIEW_BANDS, shaderBound: SKYVIEW_SHADER_BOUND },
  { layout: "bruneton2017", textures: 3, bands: BRUNETON_BANDS, shaderBound: SHADER_BOUND },
];

function cross(alts, suns, zeniths, azimuths) {
  const out = [];
  for (const h of alts) for (const e of suns) for (const z of zeniths) for (const a of azimuths) {
    // Away from the sun's disk and aureole (the product's probes hold the diffuse sky).
    const sun = [Math.cos((e * Math.PI) / 180), 0, Math.sin((e * Math.PI) / 180)];
    if (dot(view(z, a), sun) > Math.cos((8 * Math.PI) / 180)) continue;
    out.push({ h, e, z, a });
  }
  return out;
}

// Views `deltas` degrees from the sun (above it, and beside it at its elevation).
function aureole(alts, suns, deltas) {
  const out = [];
  for (const h of alts) for (const e of suns) for (const d of deltas) {
    out.push({ h, e, z: 90 - e - d, a: 0 });
    // Beside the sun: the azimuth whose angle to the sun is d at elevation e.
    const c = (Math.cos((d * Math.PI) / 180) - Math.sin((e * Math.PI) / 180) ** 2) / Math.cos((e * Math.PI) / 180) ** 2;
    out.push({ h, e, z: 90 - e, a: (Math.acos(c) * 180) / Math.PI });
  }
  return out;
}

function dot(u, v) { return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]; }
function view(zDeg, aDeg) {
  const z = (zDeg * Math.PI) / 180, a = (aDeg * Math.PI) / 180;
  return [Math.sin(z) * Math.cos(a), Math.sin(z) * Math.sin(a), Math.cos(z)];
}
function sunDir(eDeg) {
  const e = (eDeg * Math.PI) / 180;
  return [Math.cos(e), 0, Math.sin(e)];
}

let passed = 0;
let failed = 0;
function check(name, ok, detail = "") {
  if (ok) { passed++; console.log(`ok   ${name} ${detail}`); } else { failed++; console.log(`FAIL ${name} ${detail}`); }
}

async function getJson(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
  return r.json();
}

const { child, addr, cache } = await startServer(binary);
const base = `http://${addr}`;
const work = mkdtempSync(join(tmpdir(), "skybake-lut-test-"));
const browser = await chromium.launch({
  executablePath: chromePath,
  headless: true,
  args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-quic",
    "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync"],
});
const tStart = Date.now();
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  const consoleErrors = [];
  page.on("console", (m) => { if (m.type() === "error") consoleErrors.push(m.text()); });
  page.on("pageerror", (e) => consoleErrors.push(String(e)));
  await page.goto(base + "/", { waitUntil: "load", timeout: 300000 });
  // A generous wait: on the shared machine under load the first page load took over 30 s.
  await page.waitForSelector("#atmosphere", { timeout: 300000 });
  // The page's own product refresh on load (a dome, a panorama, the sky and sun documents) must
  // finish first: on a slow machine its second round of requests would otherwise land while the
  // live sky's sliders move and be counted against them.
  await page.waitForFunction(() => {
    const t = document.getElementById("status").textContent;
    return t.startsWith("Sun elevation") || t.startsWith("Error");
  }, null, { timeout: 1800000 });
  // The conditions the bundle is requested for (set without an input event: no product refresh).
  await page.evaluate(([atm, albedo, q]) => {
    document.getElementById("atmosphere").value = atm;
    document.getElementById("albedo").value = albedo;
    document.getElementById("quality").value = q;
  }, [ATMOSPHERE, ALBEDO, QUALITY]);
  check("the viewer's default layout is skyview", await page.inputValue("#live-layout") === "skyview");
  for (const spec of LAYOUTS) await testLayout(page, spec);
  check("no console errors", consoleErrors.length === 0, consoleErrors.join(" | "));
} catch (e) {
  check("live sky test ran", false, String(e && e.stack || e));
} finally {
  await browser.close();
  child.kill("SIGTERM");
  rmSync(cache, { recursive: true, force: true });
  rmSync(work, { recursive: true, force: true });
}
console.log(`${passed} passed, ${failed} failed (${((Date.now() - tStart) / 1000).toFixed(0)} s)`);
process.exit(failed === 0 ? 0 : 1);

/** Loads the bundle of `spec.layout` through the page and checks it (a) against the reader and
 *  (b) against the sky product. */
async function testLayout(page, { layout, textures, bands, shaderBound }) {
  const L = `[${layout}]`;
  await page.selectOption("#live-layout", layout);
  const lutRequests = [];
  const onLut = (r) => { if (r.url().includes("/v1/lut")) lutRequests.push(r.url()); };
  page.on("request", onLut);
  const t0 = Date.now();
  await page.click("#live-load");
  await page.waitForFunction((f) => {
    const t = document.getElementById("live-status").textContent;
    return t.startsWith("Error") || (t.startsWith("Live sky") && t.includes(`layout ${f}`));
  }, layout, { timeout: 1800000 });
  page.off("request", onLut);
  const status = await page.textContent("#live-status");
  check(`${L} bundle loaded into WebGL2`, status.startsWith("Live sky"), `${status} (${((Date.now() - t0) / 1000).toFixed(0)} s with the bundle's computation)`);
  check(`${L} bundle fetched once: manifest + ${textures} textures`, lutRequests.length === 1 + textures, lutRequests.join(" "));

  // Interactive: sliders re-render without any request.
  const requestsBefore = [];
  const onAny = (r) => requestsBefore.push(r.url());
  page.on("request", onAny);
  const canvas = () => page.evaluate(() => document.getElementById("live-canvas").toDataURL());
  for (const [id, value] of [["live-sun", "30"], ["live-sun", "-4"], ["live-altitude", "4"], ["live-exposure", "8"],
    ["live-altitude", "0"], ["live-exposure", "0"], ["live-sun", "10"]]) {
    const before = await canvas();
    await page.evaluate(([i, v]) => {
      const s = document.getElementById(i);
      s.value = v;
      s.dispatchEvent(new Event("input", { bubbles: true }));
    }, [id, value]);
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    const after = await canvas();
    check(`${L} picture changes with ${id} = ${value}`, after !== before);
    if (shots) await page.locator("#live-canvas").screenshot({ path: join(shots, `live-${layout}-${id}-${value}.png`) });
  }
  page.off("request", onAny);
  check(`${L} no request while the sliders move`, requestsBefore.length === 0, requestsBefore.join(" "));
  const frameMs = await page.evaluate(() => {
    const gl = liveSky.gl;
    liveSky.render(liveSettings());
    gl.finish();
    const t = performance.now();
    for (let i = 0; i < 5; i++) liveSky.render(liveSettings());
    gl.finish();
    return (performance.now() - t) / 5;
  });
  console.log(`info ${L} frame time ${frameMs.toFixed(1)} ms for 1024x256 pixels (software WebGL, SwiftShader)`);

  // The queries: every band's sky directions, plus aerial-perspective and irradiance queries.
  const layoutParam = layout === "bruneton2017" ? "" : `&layout=${layout}`;
  const manifest = await getJson(`${base}/v1/lut?atmosphere=${ATMOSPHERE}&ground_albedo=${ALBEDO}&quality=${QUALITY}${layoutParam}`);
  check(`${L} manifest format`, manifest.format === layout, manifest.format);
  const R = manifest.atmosphere_parameters.bottom_radius;
  const perWatt = manifest.units.texture_value_per_watt;
  const queries = [];
  const skyIndex = [];
  bands.forEach((band, b) => band.cases.forEach((c, k) => {
    skyIndex.push({ b, k, q: queries.length });
    queries.push({ function: "sky_radiance", camera: [0, 0, R + c.h], view: view(c.z, c.a), sun: sunDir(c.e),
      band: band.name });
  }));
  for (const h of [0, 2000, 10000]) for (const e of [30, 5, -2]) for (const [dep, az] of [[0.3, 90], [2, 180], [10, 30]]) {
    // The ground point the view ray `dep` degrees below the horizon meets (visible from the
    // camera, as a renderer's depth buffer gives it).
    const camera0 = [0, 0, R + h + 1];
    const dip = (Math.acos(R / (R + h + 1)) * 180) / Math.PI;
    const v = view(90 + dip + dep, az);
    const b = dot(camera0, v), c = dot(camera0, camera0) - R * R;
    const d = -b - Math.sqrt(b * b - c);
    const point = camera0.map((x, k) => x + d * v[k]);
    const camera = [0, 0, R + h + 1];
    queries.push({ function: "sky_radiance_to_point", camera, point, sun: sunDir(e) });
    // The in-scatter of the whole ray: the scale of GetSkyRadianceToPoint's two-lookup difference.
    const off = point.map((x, k) => x - camera[k]);
    const len = Math.hypot(...off);
    queries.push({ function: "sky_radiance", camera, view: off.map((x) => x / len), sun: sunDir(e), scaleOnly: true });
  }
  for (const h of [0, 3000, 20000]) for (const e of [70, 30, 5, -5]) {
    queries.push({ function: "sun_and_sky_irradiance", point: [0, 0, R + h], normal: [0, 0, 1], sun: sunDir(e) });
    queries.push({ function: "sun_and_sky_irradiance", point: [0, 0, R + h], normal: view(60, 0), sun: sunDir(e) });
  }
  const gpu = await page.evaluate((q) => liveSky.probe(q), queries);

  // (a) the reference reader on the same files, downloaded as a client would.
  const dir = join(work, layout);
  mkdirSync(dir);
  writeFileSync(join(dir, "manifest.json"), JSON.stringify(manifest));
  for (const t of Object.values(manifest.textures)) {
    const r = await fetch(base + manifest.links[t.file]);
    writeFileSync(join(dir, t.file), Buffer.from(await r.arrayBuffer()));
  }
  writeFileSync(join(work, `${layout}-queries.json`), JSON.stringify({ queries }));
  const cpu = JSON.parse(execFileSync(binary, ["lut-eval", dir, join(work, `${layout}-queries.json`)],
    { maxBuffer: 1 << 28 }).toString());
  check(`${L} lut-eval read the ${layout} layout`, cpu.format === layout, cpu.format);
  const worst = {};
  queries.forEach((q, i) => {
    if (q.scaleOnly) return;
    const c = cpu.results[i];
    // GetSkyRadianceToPoint subtracts two interpolated lookups: its deviation is relative to the
    // whole ray's in-scatter (the next query), not to the difference, which may be ~0 or < 0.
    const floor = q.function === "sky_radiance_to_point" ? cpu.results[i + 1].radiance : null;
    const [first, second] = q.function === "sun_and_sky_irradiance"
      ? [c.sun_irradiance, c.sky_irradiance] : [c.radiance, c.transmittance];
    const pairs = [[`${q.function} ${q.function === "sun_and_sky_irradiance" ? "sun" : "radiance"}`, first, gpu[i].first, false],
      [`${q.function} ${q.function === "sun_and_sky_irradiance" ? "sky irradiance" : "transmittance"}`, second, gpu[i].second,
        q.function !== "sun_and_sky_irradiance"]];
    // GetSkyRadianceToPoint from 1 m above the ground is the hardest case for 32-bit radii
    // (web/lut/atmosphere.glsl, RhoAlong): reported as its own group.
    const group = q.function === "sky_radiance_to_point"
      ? (Math.hypot(...q.camera) - R < 100 ? " (camera 1 m above the ground)" : " (camera 2-10 km)")
      : q.band ? ` (${q.band})` : "";
    for (const [whatBase, ref, got, absolute] of pairs) {
      const what = whatBase + group;
      for (let ch = 0; ch < 3; ch++) {
        const scale = Math.max(...ref.map(Math.abs));
        let dev;
        if (absolute) dev = Math.abs(got[ch] - ref[ch]);
        else if (scale === 0) dev = Math.abs(got[ch]);
        else dev = Math.abs(got[ch] - ref[ch]) / Math.max(Math.abs(ref[ch]), 1e-3 * scale, floor && !absolute ? floor[ch] : 0);
        if (!Number.isFinite(got[ch])) dev = Infinity;
        if (!worst[what] || dev > worst[what].dev) {
          worst[what] = { dev, i, ch, ref: ref[ch], got: got[ch] };
        }
      }
    }
  });
  for (const [what, w] of Object.entries(worst)) {
    const absolute = what.includes("transmittance");
    const bound = absolute ? shaderBound.transmittance : shaderBound.relative;
    check(`${L} (a) shader = reader: ${what}`, w.dev <= bound,
      `max ${absolute ? "abs" : "rel"} deviation ${w.dev.toExponential(2)} (bound ${bound}; query ${w.i} channel ${w.ch}: reader ${w.ref.toExponential(4)}, shader ${w.got.toExponential(4)})`);
  }

  // (b) the sky product at the same directions, one request per (altitude, sun).
  for (const [b, band] of bands.entries()) {
    const groups = new Map();
    band.cases.forEach((c, k) => {
      const key = `${c.h}:${c.e}`;
      if (!groups.has(key)) groups.set(key, []);
      groups.get(key).push(k);
    });
    const worstBand = { err: 0 };
    const perChannel = [0, 0, 0];
    for (const [key, ks] of groups) {
      const [h, e] = key.split(":").map(Number);
      const probe = ks.map((k) => `${band.cases[k].z}:${band.cases[k].a}`).join(",");
      const wl = manifest.channels.map((c) => c.wavelength_nm);
      const doc = await getJson(`${base}/v1/sky?atmosphere=${ATMOSPHERE}&ground_albedo=${ALBEDO}&quality=${QUALITY}` +
        `&method=precise&observer_altitude_m=${h}&sun_elevation_deg=${e}&wavelengths=${wl.join(",")}&probe=${probe}`);
      ks.forEach((k, j) => {
        const q = skyIndex.find((s) => s.b === b && s.k === k).q;
        for (let ch = 0; ch < 3; ch++) {
          const w = doc.wavelengths_nm.findIndex((x) => Math.abs(x - wl[ch]) < 1e-6);
          const product = doc.probes[j].radiance_w_m2_sr_nm[w];
          const shader = gpu[q].first[ch] / perWatt;
          const err = Math.abs(shader - product) / product;
          perChannel[ch] = Math.max(perChannel[ch], err);
          if (!(err <= worstBand.err)) Object.assign(worstBand, { err, c: band.cases[k], ch, product, shader });
        }
      });
    }
    const c = worstBand.c;
    const bound = band.assert === "target" ? band.target : band.bound;
    check(`${L} (b) shader vs sky product: ${band.name}`, worstBand.err <= bound,
      `max ${(100 * worstBand.err).toFixed(2)} % (R ${(100 * perChannel[0]).toFixed(2)}, G ${(100 * perChannel[1]).toFixed(2)}, B ${(100 * perChannel[2]).toFixed(2)} %; ` +
      `asserted ${band.assert === "target" ? "the issue's target" : "the measured bound"} ${(100 * bound).toFixed(1)} %; issue target ${(100 * band.target).toFixed(0)} %: ${worstBand.err <= band.target ? "met" : "NOT met"}; ` +
      `${band.cases.length} directions; worst at h ${c.h} m, sun ${c.e}°, view zenith ${c.z}°, azimuth ${c.a}°, channel ${"RGB"[worstBand.ch]}: ` +
      `product ${worstBand.product.toExponential(4)}, shader ${worstBand.shader.toExponential(4)} W m-2 sr-1 nm-1)`);
  }
}
