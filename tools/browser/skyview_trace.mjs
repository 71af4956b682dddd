// Debug tool (not a test): the intermediate quantities of one `skyview` sky query in the shader
// (web/lut/skyview.glsl, through the debug fragment shader tools/browser/skyview_trace.glsl, in
// Debian's headless Chromium, software WebGL, float framebuffer) beside the reader's
// (crates/harness/examples/skyview_trace.rs, SkyViewReader's steps), line by line with the
// largest relative difference of each line: the first line that differs locates a deviation of
// the shader from the reader (tools/browser/lut_test.mjs's check (a)).
//
// Usage: node tools/browser/skyview_trace.mjs BUNDLE_DIR TRACE_BINARY ALTITUDE_M SUN_DEG
//        VIEW_ZENITH_DEG AZIMUTH_DEG
// BUNDLE_DIR: a `skyview` RGB bundle (skybake lut --layout skyview --wavelengths 680,550,440 -o
// DIR); TRACE_BINARY: the built example (target/release/examples/skyview_trace).
import { execFileSync } from "node:child_process";
import { readFileSync } from "node:fs";
import { join, dirname, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { chromium } from "playwright-core";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..", "..");
const [bundle, traceBinary, ...q] = process.argv.slice(2);
if (q.length !== 4) {
  console.error("usage: skyview_trace.mjs BUNDLE_DIR TRACE_BINARY ALTITUDE_M SUN_DEG VIEW_ZENITH_DEG AZIMUTH_DEG");
  process.exit(2);
}
const [h, e, z, a] = q.map(Number);

// The reader's trace: `name v1 v2 ...` per line.
const lines = execFileSync(resolve(traceBinary), [resolve(bundle), ...q], { maxBuffer: 1 << 26 })
  .toString().trim().split("\n").map((l) => {
    const [name, ...v] = l.trim().split(/\s+/);
    return { name, values: v.map(Number) };
  });
const total = lines.reduce((n, l) => n + l.values.length, 0);

const manifest = JSON.parse(readFileSync(join(bundle, "manifest.json"), "utf8"));
const R = manifest.atmosphere_parameters.bottom_radius;
const rad = (d) => (d * Math.PI) / 180;
const camera = [0, 0, R + h];
const view = [Math.sin(rad(z)) * Math.cos(rad(a)), Math.sin(rad(z)) * Math.sin(rad(a)), Math.cos(rad(z))];
const sun = [Math.cos(rad(e)), 0, Math.sin(rad(e))];

const origin = "http://trace.local";
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
});
try {
  const page = await browser.newPage();
  page.on("console", (m) => { if (m.type() === "error") console.error(m.text()); });
  await page.route(`${origin}/**`, (route) => {
    const path = new URL(route.request().url()).pathname;
    if (path === "/") return route.fulfill({ contentType: "text/html", body: "<canvas id=c width=64 height=64></canvas>" });
    if (path.startsWith("/bundle/")) {
      const file = path.slice("/bundle/".length);
      if (file === "manifest.json") {
        const m = { ...manifest, links: Object.fromEntries(Object.values(manifest.textures).map((t) => [t.file, `/bundle/${t.file}`])) };
        return route.fulfill({ contentType: "application/json", body: JSON.stringify(m) });
      }
      return route.fulfill({ body: readFileSync(join(bundle, file)) });
    }
    const local = path === "/trace.glsl" ? join(root, "tools", "browser", "skyview_trace.glsl") : join(root, "web", "lut", path.slice(1));
    return route.fulfill({ body: readFileSync(local) });
  });
  await page.goto(`${origin}/`);
  await page.addScriptTag({ url: `${origin}/exr.js` });
  await page.addScriptTag({ url: `${origin}/sky.js` });
  const out = await page.evaluate(async ({ camera, view, sun, total }) => {
    const text = (u) => fetch(u).then((r) => r.text());
    const [glsl, skyviewGlsl, traceGlsl] = await Promise.all(["/atmosphere.glsl", "/skyview.glsl", "/trace.glsl"].map(text));
    const sky = new LiveSky(document.getElementById("c"), glsl, skyviewGlsl);
    let probeSource = null;
    const compile = sky.program.bind(sky);
    sky.program = (vs, fs) => {
      if (fs.includes("#define PROBES\n")) probeSource = fs;
      return compile(vs, fs);
    };
    await sky.load("/bundle/manifest.json");
    // The shipped shader's value of the query (the probe path of lut_test.mjs).
    const probe = sky.probe([{ function: "sky_radiance", camera, view, sun }])[0].first;
    // The trace program: the probe program's source without its main, plus the trace's.
    const p = compile(sky.vs, probeSource.replace("#define PROBES\n", "") + "\n" + traceGlsl);
    sky.bindBundle(p);
    const gl = sky.gl;
    gl.uniform3fv(gl.getUniformLocation(p, "trace_camera"), camera);
    gl.uniform3fv(gl.getUniformLocation(p, "trace_view"), view);
    gl.uniform3fv(gl.getUniformLocation(p, "trace_sun"), sun);
    const target = gl.createTexture();
    gl.activeTexture(gl.TEXTURE9);
    gl.bindTexture(gl.TEXTURE_2D, target);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, total, 1, 0, gl.RGBA, gl.FLOAT, null);
    const fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
    gl.viewport(0, 0, total, 1);
    gl.bindVertexArray(sky.vao);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    const px = new Float32Array(4 * total);
    gl.readPixels(0, 0, total, 1, gl.RGBA, gl.FLOAT, px);
    return { probe, values: Array.from({ length: total }, (_, i) => px[4 * i]), count: px[1] };
  }, { camera, view, sun, total });
  if (out.count !== total) console.log(`WARNING: the shader traced ${out.count} values, the reader ${total}: the orders differ`);
  let k = 0;
  for (const l of lines) {
    const got = out.values.slice(k, k + l.values.length);
    k += l.values.length;
    let dev = 0;
    l.values.forEach((x, i) => {
      const d = Math.abs(got[i] - x) / Math.max(Math.abs(x), 1e-30);
      if (x !== got[i]) dev = Math.max(dev, d);
    });
    console.log(`${dev > 1e-6 ? "DIFF" : "    "} ${l.name.padEnd(34)} rel ${dev.toExponential(2)}\n       reader ${l.values.map((x) => x.toExponential(7)).join(" ")}\n       shader ${got.map((x) => x.toExponential(7)).join(" ")}`);
  }
  console.log(`shipped shader (probe): ${out.probe.map((x) => x.toExponential(7)).join(" ")}`);
} finally {
  await browser.close();
}
