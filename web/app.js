// skybake viewer: plain JavaScript against the public HTTP API (/v1/...). No build step, no CDN.
"use strict";

const $ = (id) => document.getElementById(id);
const SPECTRUM_NM = Array.from({ length: 21 }, (_, i) => 380 + 20 * i); // 380…780 nm

// ---- parameters -------------------------------------------------------------------------------

/** Observer altitude from the logarithmic slider: 0 m … 1000 km. */
function altitudeM() {
  const v = Number($("altitude").value);
  return v <= 0 ? 0 : Math.round(Math.pow(10, v) - 1);
}

function formatAltitude(m) {
  return m >= 10000 ? `${(m / 1000).toFixed(0)} km` : `${m} m`;
}

/** The query parameters shared by every product, from the form. */
function commonParams() {
  const p = new URLSearchParams();
  if ($("sun-mode").value === "place") {
    p.set("latitude_deg", $("latitude").value);
    p.set("longitude_deg", $("longitude").value);
    const t = $("time").value; // yyyy-mm-ddThh:mm, read as UTC
    p.set("time", `${t.length === 16 ? t + ":00" : t}Z`);
  } else {
    p.set("sun_elevation_deg", $("sun-elevation").value);
  }
  p.set("observer_altitude_m", String(altitudeM()));
  p.set("atmosphere", $("atmosphere").value);
  p.set("ground_albedo", $("albedo").value);
  if ($("haze").value) {
    p.set("aerosol_type", $("haze").value);
    p.set("visibility_km", $("visibility").value);
  }
  p.set("method", $("method").value);
  p.set("quality", $("quality").value);
  return p;
}

function url(path, params, extra = {}) {
  const p = new URLSearchParams(params);
  for (const [k, v] of Object.entries(extra)) p.set(k, v);
  return `${path}?${p.toString()}`;
}

/** fetch that turns a problem+json answer into an Error carrying its detail. */
async function fetchOk(input, init) {
  const r = await fetch(input, init);
  if (!r.ok) {
    let detail = `${r.status} ${r.statusText}`;
    try {
      const problem = await r.json();
      detail = problem.detail || problem.title || detail;
    } catch (_) { /* not JSON */ }
    const e = new Error(detail);
    e.status = r.status;
    throw e;
  }
  return r;
}

function setStatus(text) {
  $("status").textContent = text;
}

// ---- images with an exposure control ----------------------------------------------------------

const SRGB_TO_LINEAR = new Float32Array(256).map((_, i) => {
  const c = i / 255;
  return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
});

function linearToSrgb8(x) {
  const c = x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055;
  return Math.max(0, Math.min(255, Math.round(c * 255)));
}

const loadedImages = { fisheye: null, panorama: null };

async function loadImage(src) {
  const r = await fetchOk(src);
  const blob = await r.blob();
  const bitmap = await createImageBitmap(blob);
  return { bitmap, headers: r.headers };
}

function drawExposed(canvasId, bitmap) {
  const canvas = $(canvasId);
  canvas.width = bitmap.width;
  canvas.height = bitmap.height;
  const ctx = canvas.getContext("2d");
  ctx.drawImage(bitmap, 0, 0);
  const gain = Math.pow(2, Number($("exposure").value));
  if (gain === 1) return;
  const img = ctx.getImageData(0, 0, canvas.width, canvas.height);
  const d = img.data;
  const lut = new Uint8ClampedArray(256).map((_, i) => linearToSrgb8(SRGB_TO_LINEAR[i] * gain));
  for (let i = 0; i < d.length; i += 4) {
    d[i] = lut[d[i]];
    d[i + 1] = lut[d[i + 1]];
    d[i + 2] = lut[d[i + 2]];
  }
  ctx.putImageData(img, 0, 0);
}

function redrawExposure() {
  $("exposure-value").textContent = `${$("exposure").value} EV`;
  if (loadedImages.fisheye) drawExposed("fisheye", loadedImages.fisheye);
  if (loadedImages.panorama) drawExposed("panorama", loadedImages.panorama);
}

// ---- plots --------------------------------------------------------------------------------------

/** A small line plot: series = [{label, x, y, colour}], with axes and a legend. */
function plot(canvasId, series, { xLabel, yLabel, logY = false } = {}) {
  const canvas = $(canvasId);
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height;
  const m = { l: 58, r: 10, t: 10, b: 34 };
  ctx.clearRect(0, 0, W, H);
  ctx.fillStyle = getComputedStyle(document.body).getPropertyValue("--plot-bg") || "#fff";
  ctx.fillRect(0, 0, W, H);
  const xs = series.flatMap((s) => s.x);
  const tr = (v) => (logY ? Math.log10(Math.max(v, 1e-12)) : v);
  const ys = series.flatMap((s) => s.y.map(tr)).filter(Number.isFinite);
  if (xs.length === 0 || ys.length === 0) return;
  const [x0, x1] = [Math.min(...xs), Math.max(...xs)];
  let [y0, y1] = [Math.min(...ys), Math.max(...ys)];
  if (!logY) y0 = Math.min(0, y0);
  if (y1 === y0) y1 = y0 + 1;
  const px = (x) => m.l + ((x - x0) / (x1 - x0 || 1)) * (W - m.l - m.r);
  const py = (y) => H - m.b - ((tr(y) - y0) / (y1 - y0)) * (H - m.t - m.b);
  ctx.strokeStyle = "#888";
  ctx.fillStyle = "#444";
  ctx.font = "11px sans-serif";
  ctx.beginPath();
  ctx.moveTo(m.l, m.t);
  ctx.lineTo(m.l, H - m.b);
  ctx.lineTo(W - m.r, H - m.b);
  ctx.stroke();
  for (let k = 0; k <= 4; k++) {
    const yv = y0 + ((y1 - y0) * k) / 4;
    const yy = H - m.b - ((H - m.t - m.b) * k) / 4;
    const text = logY ? `1e${yv.toFixed(1)}` : yv.toPrecision(3);
    ctx.fillText(text, 2, yy + 4);
  }
  for (let k = 0; k <= 4; k++) {
    const xv = x0 + ((x1 - x0) * k) / 4;
    ctx.fillText(xv.toFixed(0), px(xv) - 10, H - m.b + 14);
  }
  ctx.fillText(xLabel || "", W / 2 - 30, H - 4);
  ctx.save();
  ctx.translate(10, H / 2 + 40);
  ctx.rotate(-Math.PI / 2);
  ctx.restore();
  series.forEach((s, i) => {
    ctx.strokeStyle = s.colour;
    ctx.lineWidth = 2;
    ctx.beginPath();
    s.x.forEach((x, j) => {
      const y = py(s.y[j]);
      if (j === 0) ctx.moveTo(px(x), y); else ctx.lineTo(px(x), y);
    });
    ctx.stroke();
    ctx.fillStyle = s.colour;
    ctx.fillText(s.label, W - m.r - 190, m.t + 12 + 13 * i);
  });
  ctx.fillStyle = "#444";
  ctx.fillText(yLabel || "", m.l + 6, m.t + 10);
}

// ---- products -----------------------------------------------------------------------------------

function describeDetails(name, doc) {
  const meta = doc.meta || {};
  const stages = meta.plan || meta.stages || doc.plan || doc.stages;
  const err = doc.error_estimate || meta.error_estimate;
  const lines = [];
  lines.push(`<h3>${name}</h3>`);
  if (doc.timing_ms !== undefined) lines.push(`<p>Computed in ${Number(doc.timing_ms).toFixed(1)} ms.</p>`);
  if (err) {
    const relative = err.relative_error ?? err.path_tracer_relative_noise;
    const rel = relative !== undefined && relative !== null ? `${(100 * relative).toFixed(2)} %` : "?";
    lines.push(`<p>Error estimate: ${rel} (${escapeHtml(err.method || err.basis || "")}${err.validated === false ? ", not validated here" : ""}).` +
      `${err.caveat ? ` <em>${escapeHtml(err.caveat)}</em>` : ""}</p>`);
  }
  if (stages) lines.push(`<pre>${escapeHtml(JSON.stringify(stages, null, 1))}</pre>`);
  return lines.join("");
}

function escapeHtml(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
}

let generation = 0;

async function refresh() {
  const mine = ++generation;
  const p = commonParams();
  setStatus("Computing…");
  $("sky-exr").href = url("/v1/sky", p, { format: "exr" });
  $("sun-json").href = url("/v1/sun", p, { wavelengths: SPECTRUM_NM.join(",") });
  try {
    const fisheye = await loadImage(url("/v1/sky", p, { format: "png" }));
    if (mine !== generation) return;
    loadedImages.fisheye = fisheye.bitmap;
    drawExposed("fisheye", fisheye.bitmap);
    const [pano, sky, sun] = await Promise.all([
      loadImage(url("/v1/sky", p, { format: "png_latlong" })).catch(() => null),
      fetchOk(url("/v1/sky", p)).then((r) => r.json()),
      fetchOk(url("/v1/sun", p, { wavelengths: SPECTRUM_NM.join(",") })).then((r) => r.json()),
    ]);
    if (mine !== generation) return;
    if (pano) {
      loadedImages.panorama = pano.bitmap;
      drawExposed("panorama", pano.bitmap);
    }
    showSun(sun);
    $("product-details").innerHTML = describeDetails("sky", sky) + describeDetails("sun", sun);
    setStatus(`Sun elevation ${Number(sky.sun_elevation_deg).toFixed(2)}°, observer at ${formatAltitude(altitudeM())}.`);
  } catch (e) {
    if (mine === generation) setStatus(`Error: ${e.message}`);
  }
}

function showSun(sun) {
  const x = sun.wavelengths_nm;
  plot("sun-plot", [
    { label: "transmittance ×1000", x, y: sun.transmittance.map((v) => v * 1000), colour: "#555" },
    { label: "direct normal (W m⁻² nm⁻¹ ×1000)", x, y: sun.direct_normal_irradiance_w_m2_nm.map((v) => v * 1000), colour: "#d08000" },
    { label: "diffuse horizontal ×1000", x, y: sun.diffuse_horizontal_irradiance_w_m2_nm.map((v) => v * 1000), colour: "#2a6fd6" },
    { label: "global horizontal ×1000", x, y: sun.global_horizontal_irradiance_w_m2_nm.map((v) => v * 1000), colour: "#1a9a4a" },
  ], { xLabel: "wavelength (nm)" });
  const parts = [];
  if (sun.illuminance_lux !== undefined) parts.push(`horizontal illuminance ${Number(sun.illuminance_lux).toPrecision(3)} lx`);
  if (sun.correlated_colour_temperature_k !== undefined) parts.push(`CCT ${Math.round(sun.correlated_colour_temperature_k)} K`);
  $("sun-summary").textContent = parts.join(", ");
}

async function probeAt(event) {
  const canvas = $("fisheye");
  const rect = canvas.getBoundingClientRect();
  const dx = ((event.clientX - rect.left) / rect.width) * 2 - 1;
  const dy = ((event.clientY - rect.top) / rect.height) * 2 - 1;
  const r = Math.hypot(dx, dy);
  if (r > 1) return;
  const zenith = 90 * r;
  const azimuth = Math.abs((Math.atan2(dx, -dy) * 180) / Math.PI);
  const probe = `${zenith.toFixed(2)}:${azimuth.toFixed(2)}`;
  $("probe-label").textContent = `View zenith ${zenith.toFixed(1)}°, azimuth ${azimuth.toFixed(1)}° from the sun.`;
  try {
    const doc = await fetchOk(url("/v1/sky", commonParams(), { probe, wavelengths: SPECTRUM_NM.join(",") })).then((r) => r.json());
    const pr = doc.probes[0];
    plot("probe-plot", [{ label: "radiance (W m⁻² sr⁻¹ nm⁻¹)", x: doc.wavelengths_nm, y: pr.radiance_w_m2_sr_nm, colour: "#2a6fd6" }],
      { xLabel: "wavelength (nm)" });
  } catch (e) {
    $("probe-label").textContent = `Error: ${e.message}`;
  }
}

// ---- cloud frames -------------------------------------------------------------------------------

async function loadScenes() {
  try {
    const list = await fetchOk("/v1/scenes").then((r) => r.json());
    const select = $("scene");
    // Only frame scenes (with a camera) render; the others are cloud sections for `skybake clouds`.
    for (const s of list.scenes.filter((x) => x.frame)) {
      const o = document.createElement("option");
      o.value = s.name;
      o.textContent = s.description ? `${s.name}: ${s.description}` : s.name;
      select.appendChild(o);
    }
  } catch (e) {
    $("frame-caption").textContent = `Cloud frames unavailable: ${e.message}`;
    $("render").disabled = true;
  }
}

async function renderFrame() {
  const name = $("scene").value;
  if (!name) return;
  $("frame-caption").textContent = "Rendering…";
  $("render").disabled = true;
  try {
    const scene = await fetchOk(`/v1/scenes/${encodeURIComponent(name)}`).then((r) => r.text());
    const headers = { "content-type": "application/json" };
    // The spectral frame first: the PNG and the summary are then made from it (a PNG alone
    // would be an RGB-only request, computed on its own).
    const exr = await fetchOk("/v1/render?format=exr", { method: "POST", headers, body: scene }).then((r) => r.blob());
    const png = await fetchOk("/v1/render?format=png", { method: "POST", headers, body: scene }).then((r) => r.blob());
    $("frame").src = URL.createObjectURL(png);
    const meta = await fetchOk("/v1/render?format=json", { method: "POST", headers, body: scene }).then((r) => r.json());
    $("frame-caption").innerHTML = describeDetails(`frame: ${escapeHtml(name)}`, meta);
    $("frame-exr").href = URL.createObjectURL(exr);
    $("frame-exr").download = `${name}.exr`;
    $("frame-exr").hidden = false;
  } catch (e) {
    $("frame-caption").textContent = `Error: ${e.message}`;
  } finally {
    $("render").disabled = false;
  }
}

// ---- bake jobs ----------------------------------------------------------------------------------

async function createJob(event) {
  event.preventDefault();
  const p = Object.fromEntries(commonParams());
  delete p.sun_elevation_deg;
  delete p.latitude_deg;
  delete p.longitude_deg;
  delete p.time;
  for (const k of ["observer_altitude_m", "ground_albedo"]) p[k] = Number(p[k]);
  const body = {
    grids: [{
      product: "sky", ...p,
      sweep: { sun_elevation_deg: { from: Number($("bake-from").value), to: Number($("bake-to").value), step: Number($("bake-step").value) } },
    }],
  };
  $("bake-status").textContent = "Creating the job…";
  $("bake-artifacts").innerHTML = "";
  try {
    const job = await fetchOk("/v1/jobs", { method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(body) }).then((r) => r.json());
    pollJob(job.id);
  } catch (e) {
    $("bake-status").textContent = `Error: ${e.message}`;
  }
}

async function pollJob(id) {
  try {
    const s = await fetchOk(`/v1/jobs/${encodeURIComponent(id)}`).then((r) => r.json());
    $("bake-progress").max = s.total || 1;
    $("bake-progress").value = s.done || 0;
    $("bake-status").textContent = `Job ${id}: ${s.state}, ${s.done}/${s.total} done${s.errors && s.errors.length ? `, ${s.errors.length} errors` : ""}.`;
    if (s.state === "queued" || s.state === "running") {
      setTimeout(() => pollJob(id), 500);
    } else {
      const list = $("bake-artifacts");
      list.innerHTML = "";
      const items = (s.artifacts && s.artifacts.items) || [];
      for (const a of items) {
        const li = document.createElement("li");
        if (a.status === "done") {
          const link = document.createElement("a");
          link.href = `${a.url}?format=exr`;
          link.textContent = `${a.product} #${a.index} (EXR)`;
          li.appendChild(link);
        } else {
          li.textContent = `${a.product} #${a.index}: ${a.status}`;
        }
        list.appendChild(li);
      }
    }
  } catch (e) {
    $("bake-status").textContent = `Error: ${e.message}`;
  }
}

// ---- live sky (WebGL2, the real-time texture bundle) --------------------------------------------

let liveSky = null;
let liveFrame = 0;

function liveSettings() {
  const v = Number($("live-altitude").value);
  return {
    sunElevationDeg: Number($("live-sun").value),
    altitudeM: v <= 0 ? 0 : Math.round(Math.pow(10, v) - 1),
    // 1 − exp(−L · exposure) with L in mW m⁻² sr⁻¹ nm⁻¹: 0 EV shows a day sky mid-grey.
    exposure: 0.01 * Math.pow(2, Number($("live-exposure").value)),
  };
}

function drawLive() {
  const s = liveSettings();
  $("live-sun-value").textContent = `${s.sunElevationDeg}°`;
  $("live-altitude-value").textContent = formatAltitude(s.altitudeM);
  $("live-exposure-value").textContent = `${$("live-exposure").value} EV`;
  if (!liveSky || !liveSky.manifest) return;
  cancelAnimationFrame(liveFrame);
  liveFrame = requestAnimationFrame(() => liveSky.render(s));
}

async function loadLive() {
  const p = new URLSearchParams();
  for (const k of ["atmosphere", "ground_albedo", "quality"]) p.set(k, commonParams().get(k));
  // The skyview layout by default: it meets the accuracy targets by day (docs/lut.md); its
  // shader draws the sky, the ground's light and the aerial perspective.
  const layout = $("live-layout").value;
  if (layout !== "bruneton2017") p.set("layout", layout);
  $("live-status").textContent = "Fetching the bundle…";
  $("live-load").disabled = true;
  try {
    if (!liveSky) {
      const [glsl, skyviewGlsl] = await Promise.all(["/assets/lut-atmosphere.glsl", "/assets/lut-skyview.glsl"]
        .map((u) => fetchOk(u).then((r) => r.text())));
      liveSky = new LiveSky($("live-canvas"), glsl, skyviewGlsl);
    }
    const t0 = performance.now();
    const m = await liveSky.load(url("/v1/lut", p), fetchOk);
    $("live-status").textContent = `Live sky: ${p.get("atmosphere")}, layout ${m.format}, quality ${m.request.quality}, ` +
      `bundle loaded in ${((performance.now() - t0) / 1000).toFixed(1)} s.`;
    drawLive();
  } catch (e) {
    $("live-status").textContent = `Error: ${e.message}`;
  } finally {
    $("live-load").disabled = false;
  }
}

// ---- wiring -------------------------------------------------------------------------------------

let timer = null;
function scheduleRefresh() {
  clearTimeout(timer);
  timer = setTimeout(refresh, 250);
}

function updateLabels() {
  $("sun-elevation-value").textContent = `${$("sun-elevation").value}°`;
  $("altitude-value").textContent = formatAltitude(altitudeM());
  $("albedo-value").textContent = Number($("albedo").value).toFixed(2);
  const place = $("sun-mode").value === "place";
  $("sun-place-group").hidden = !place;
  $("sun-elevation-group").hidden = place;
}

$("conditions").addEventListener("input", () => { updateLabels(); scheduleRefresh(); });
$("conditions").addEventListener("submit", (e) => e.preventDefault());
$("exposure").addEventListener("input", redrawExposure);
$("fisheye").addEventListener("click", probeAt);
$("render").addEventListener("click", renderFrame);
$("bake-form").addEventListener("submit", createJob);
$("live-load").addEventListener("click", loadLive);
for (const id of ["live-sun", "live-altitude", "live-exposure"]) $(id).addEventListener("input", drawLive);
drawLive();
updateLabels();
refresh();
loadScenes();
