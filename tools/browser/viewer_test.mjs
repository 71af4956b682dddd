// Browser test of the viewer: starts `skybake serve` on a loopback port with a scratch
// cache, opens `/` in Debian's headless Chromium (playwright-core), moves the sun slider, waits for
// the new sky image, and checks that it changed, that the page logged no console errors, that every
// control has a label, and that the page fits a phone-sized viewport. Screenshots go to docs/.
//
// It then renders the cheapest example cloud frame through the page (POST /v1/render) and bakes a
// three-step sun sweep through the page's job form, waiting for both to finish.
//
// Usage: node tools/browser/viewer_test.mjs [path/to/skybake] [screenshot dir]
//        (defaults: target/release/skybake, docs/)
import { mkdirSync, rmSync } from "node:fs";
import { join, dirname, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { chromium } from "playwright-core";
import { startServer } from "./serve.mjs";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..", "..");
const binary = process.argv[2] || join(root, "target", "release", "skybake");
const chromePath = process.env.CHROMIUM || "/usr/bin/chromium";
const docs = process.argv[3] ? resolve(process.argv[3]) : join(root, "docs");
mkdirSync(docs, { recursive: true });

let passed = 0;
let failed = 0;
function check(name, ok, detail = "") {
  if (ok) {
    passed++;
    console.log(`ok   ${name}`);
  } else {
    failed++;
    console.log(`FAIL ${name} ${detail}`);
  }
}

const { child, addr, cache } = await startServer(binary);
const base = `http://${addr}`;
const browser = await chromium.launch({
  executablePath: chromePath,
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  const consoleErrors = [];
  page.on("console", (m) => { if (m.type() === "error") consoleErrors.push(m.text()); });
  page.on("pageerror", (e) => consoleErrors.push(String(e)));

  // The first sky is in when the status names the sun elevation.
  await page.goto(base + "/", { waitUntil: "load" });
  await page.waitForFunction(() => document.getElementById("status").textContent.startsWith("Sun elevation"),
    null, { timeout: 120000 });
  const sky = () => page.evaluate(() => document.getElementById("fisheye").toDataURL());
  const before = await sky();
  const statusBefore = await page.textContent("#status");
  check("first sky image drawn", before.length > 1000);

  // Move the sun slider to 2° and wait for the new image.
  await page.evaluate(() => {
    const s = document.getElementById("sun-elevation");
    s.value = "2";
    s.dispatchEvent(new Event("input", { bubbles: true }));
  });
  await page.waitForFunction((prev) => {
    const t = document.getElementById("status").textContent;
    return t.startsWith("Sun elevation") && t !== prev;
  }, statusBefore, { timeout: 120000 });
  const after = await sky();
  check("sky image changes when the sun moves", after !== before);
  check("status reports the new sun", (await page.textContent("#status")).includes("2.00°"));

  // Click the dome: the spectrum plot appears.
  await page.click("#fisheye", { position: { x: 256, y: 120 } });
  await page.waitForFunction(() => document.getElementById("probe-label").textContent.startsWith("View zenith"),
    null, { timeout: 60000 });
  check("spectrum at a clicked direction", true);

  // Render an example cloud frame (the smallest one the page offers).
  const scenes = await page.evaluate(() => [...document.querySelectorAll("#scene option")].map((o) => o.value));
  check("example frame scenes listed", scenes.length > 0, JSON.stringify(scenes));
  if (scenes.length > 0) {
    const pick = scenes.find((n) => n.startsWith("validation")) || scenes[0];
    await page.selectOption("#scene", pick);
    await page.click("#render");
    await page.waitForFunction(() => {
      const t = document.getElementById("frame-caption").textContent;
      return t !== "Not rendered yet." && !t.startsWith("Rendering");
    }, null, { timeout: 600000 });
    const caption = await page.textContent("#frame-caption");
    check("cloud frame rendered", !caption.startsWith("Error") && !caption.startsWith("Cloud frames unavailable"), caption);
    const frameWidth = await page.evaluate(() => document.getElementById("frame").naturalWidth);
    check("cloud frame image shown", frameWidth > 0, `naturalWidth ${frameWidth}`);
    check("frame EXR download offered", (await page.getAttribute("#frame-exr", "hidden")) === null);
  }

  // Bake a three-step sun sweep through the job form and wait for it to finish.
  await page.fill("#bake-from", "0");
  await page.fill("#bake-to", "10");
  await page.fill("#bake-step", "5");
  await page.click("#bake-form button[type=submit]");
  await page.waitForFunction(() => {
    const t = document.getElementById("bake-status").textContent;
    return /^Job .*: (completed|cancelled)/.test(t) || t.startsWith("Error");
  }, null, { timeout: 300000 });
  const bakeStatus = await page.textContent("#bake-status");
  const links = await page.evaluate(() => document.querySelectorAll("#bake-artifacts a").length);
  check("bake job finished with three artifacts", /: completed, 3\/3 done/.test(bakeStatus) && links === 3, `${bakeStatus} (${links} links)`);

  await page.screenshot({ path: join(docs, "viewer.png"), fullPage: true });

  // Every control has a label.
  const unlabelled = await page.evaluate(() => [...document.querySelectorAll("input, select, progress")]
    .filter((el) => !(el.labels && el.labels.length) && !el.getAttribute("aria-label"))
    .map((el) => el.id || el.name || el.tagName));
  check("every control has a label", unlabelled.length === 0, unlabelled.join(", "));

  // Phone-sized viewport: nothing wider than the screen.
  await page.setViewportSize({ width: 390, height: 844 });
  const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
  check("fits a 390 px wide viewport", overflow <= 1, `overflows by ${overflow} px`);
  await page.screenshot({ path: join(docs, "viewer-phone.png"), fullPage: false });

  check("no console errors", consoleErrors.length === 0, consoleErrors.join(" | "));
} catch (e) {
  check("viewer test ran", false, String(e));
} finally {
  await browser.close();
  child.kill("SIGTERM");
  rmSync(cache, { recursive: true, force: true });
}
console.log(`${passed} passed, ${failed} failed`);
process.exit(failed === 0 ? 0 : 1);
