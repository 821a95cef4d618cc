// End-to-end test of the viewer page of `volrad serve` in a real headless Chromium, one check
// per feature: it opens on a preloaded scene, rendered; the image keeps the camera's aspect;
// the scene's cameras can be picked; the URL holds scene and camera and opens the same view;
// exposure (automatic, then by hand); save; the bounding box and axes; a slice of the fluence;
// dragging to a free view and back with reset; an upload under a name with its solve report
// and residual plot; the sun and sky controls of a sky scene, and relighting it.
// Prints "N passed, M failed".
//
//   VOLRAD_BIN=target/debug/volrad CHROMIUM=/usr/bin/chromium node tests/e2e/viewer.mjs [screenshot.png]

import { spawn } from "node:child_process";
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { chromium } from "playwright-core";

const bin = process.env.VOLRAD_BIN || "target/debug/volrad";
const browserPath = process.env.CHROMIUM || "/usr/bin/chromium";
const screenshot = process.argv[2] || null;
const port = 20000 + Math.floor(Math.random() * 20000);
const cache = mkdtempSync(join(tmpdir(), "volrad-e2e-"));

// Preloaded: two cameras of different aspect, one orthographic.
const PRELOADED = `[volume]
generator = { kind = "cloud", seed = 7 }
dims = [16, 16, 12]
cell_size = 0.75

[medium]
albedo = 0.95
phase = { kind = "henyey-greenstein", g = 0.6 }

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[background]
radiance = 0.01

[solve]
method = "discrete-ordinates"

[[camera]]
name = "front"
eye = [6.0, -18.0, 4.5]
target = [6.0, 6.0, 4.5]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 480
height = 360

[[camera]]
name = "top"
projection = "orthographic"
ortho_height = 16.0
eye = [6.0, 6.0, 30.0]
target = [6.0, 6.0, 4.5]
up = [0.0, 1.0, 0.0]
width = 300
height = 300
`;

// Uploaded through the page: zonal, isotropic.
const UPLOADED = PRELOADED.replace("seed = 7", "seed = 3").replace("albedo = 0.95", "albedo = 0.9")
  .replace('phase = { kind = "henyey-greenstein", g = 0.6 }', 'phase = { kind = "isotropic" }')
  .replace('method = "discrete-ordinates"', 'method = "zonal"');

// Uploaded through the page and relit: a small cloud under a sky.
const SKY = `[volume]
generator = { kind = "cloud", seed = 5 }
dims = [12, 12, 9]

[medium]
albedo = 0.9
phase = { kind = "isotropic" }

[[light]]
kind = "sky"
sun_elevation_degrees = 40.0

[solve]
method = "discrete-ordinates"
bins = 24

[[camera]]
name = "front"
eye = [6.0, -18.0, 4.5]
target = [6.0, 6.0, 4.5]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 320
height = 240
`;

let passed = 0, failed = 0;
function check(name, ok, detail = "") {
  if (ok) { passed++; console.log(`ok   ${name}`); }
  else { failed++; console.log(`FAIL ${name} ${detail}`); }
}

async function waitForServer(url, ms) {
  const end = Date.now() + ms;
  while (Date.now() < end) {
    try { if ((await fetch(url)).ok) return true; } catch (_) { /* not up yet */ }
    await new Promise((r) => setTimeout(r, 100));
  }
  return false;
}

const sceneFile = join(cache, "puff.toml");
writeFileSync(sceneFile, PRELOADED);
const server = spawn(bin, ["--quiet", "serve", sceneFile, "--addr", `127.0.0.1:${port}`, "--cache", join(cache, "c")], { stdio: "inherit" });
let browser = null;

// The shown image's state.
const shown = (page) => page.evaluate(() => {
  const img = document.getElementById("view");
  return { n: Number(img.dataset.renders || 0), res: img.dataset.resolution, url: img.dataset.url || "",
           w: img.naturalWidth, h: img.naturalHeight, hash: location.hash, camera: document.getElementById("camera").value };
});
// Waits for a full-resolution image newer than render `n`.
const nextImage = (page, n) => page.waitForFunction((n) => {
  const img = document.getElementById("view");
  return Number(img.dataset.renders || 0) > n && img.dataset.resolution === "full" && img.complete && img.naturalWidth > 0;
}, n, { timeout: 90000 });
// Mean brightness of the shown image (0–255).
const brightness = (page) => page.evaluate(() => {
  const img = document.getElementById("view");
  const c = document.createElement("canvas");
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext("2d");
  g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let sum = 0;
  for (let i = 0; i < d.length; i += 4) sum += d[i];
  return sum / (d.length / 4);
});

try {
  const base = `http://127.0.0.1:${port}`;
  check("server starts with a scene file", await waitForServer(`${base}/v1/scenes`, 15000));
  browser = await chromium.launch({ executablePath: browserPath, args: ["--no-sandbox", "--headless=new"] });
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  await page.goto(base + "/");
  check("page loads", (await page.title()) === "volrad viewer");

  // Opens on the preloaded scene, solved by the service and rendered without a click.
  await nextImage(page, 0);
  let s = await shown(page);
  const sceneText = await page.evaluate(() => document.getElementById("scenes").selectedOptions[0].textContent);
  check("opens on the preloaded scene, by name, rendered", sceneText.startsWith("puff") && sceneText.includes("done") && s.n >= 1, sceneText);
  check("the image has the camera's aspect", Math.abs(s.w / s.h - 480 / 360) < 0.02, `${s.w}×${s.h}`);
  check("the URL holds scene and camera", /scene=[0-9a-f]{32}/.test(s.hash) && s.hash.includes("camera=front"), s.hash);
  const shared = base + "/" + s.hash.replace("camera=front", "camera=top");

  // Cameras: both listed; picking the orthographic one renders it at its own aspect.
  const cams = await page.evaluate(() => [...document.getElementById("camera").options].map((o) => o.value));
  check("the scene's cameras are listed", cams.includes("front") && cams.includes("top"), JSON.stringify(cams));
  await page.selectOption("#camera", "top");
  await nextImage(page, s.n);
  s = await shown(page);
  check("picking a camera renders it at its aspect", Math.abs(s.w / s.h - 1) < 0.02 && s.url.includes("camera=top") && s.hash.includes("camera=top"), JSON.stringify(s));
  await page.selectOption("#camera", "front");
  await nextImage(page, s.n);
  s = await shown(page);

  // Bounding box and axes drawn over the image.
  const gizmo = await page.evaluate(() => ({ box: document.querySelectorAll("#gizmo line.box").length, axes: document.querySelectorAll("#gizmo line.axis").length }));
  check("bounding box and axes drawn", gizmo.box === 12 && gizmo.axes === 3, JSON.stringify(gizmo));

  // Exposure: automatic first (no exposure asked), then two stops more by hand: brighter.
  const autoBright = await brightness(page);
  check("automatic exposure by default", !s.url.includes("exposure="), s.url);
  await page.evaluate(() => { const r = document.getElementById("exposure"); r.value = "2"; r.dispatchEvent(new Event("input")); r.dispatchEvent(new Event("change")); });
  await nextImage(page, s.n);
  s = await shown(page);
  const handBright = await brightness(page);
  const autoChecked = await page.isChecked("#auto");
  check("two stops more exposure: a brighter image", s.url.includes("exposure=") && !autoChecked && handBright > autoBright * 1.3, `${autoBright.toFixed(1)} → ${handBright.toFixed(1)}, ${s.url}`);
  await page.check("#auto");
  await nextImage(page, s.n);
  s = await shown(page);

  // Save: a link to the shown image, with a file name.
  const save = await page.evaluate(() => ({ href: document.getElementById("save").href, name: document.getElementById("save").download, src: document.getElementById("view").src }));
  check("save links the shown image", save.href === save.src && save.name.endsWith(".png"), JSON.stringify(save));

  // Dragging: low-resolution images while moving, a free view at full resolution after.
  const box = await page.locator("#view").boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  const before = s;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) {
    await page.mouse.move(cx + i * 12, cy + i * 3);
    await new Promise((r) => setTimeout(r, 30));
  }
  await page.mouse.up();
  await nextImage(page, before.n + 1);
  s = await shown(page);
  check("dragging moves to a free view, ending at full resolution", s.n > before.n + 1 && s.url !== before.url && s.camera === "" && s.hash.includes("eye="), JSON.stringify({ before, s }));
  await page.click("#reset");
  await nextImage(page, s.n);
  s = await shown(page);
  check("reset returns to the camera", s.url === before.url && s.camera === "front", JSON.stringify({ before, s }));

  // A slice of the solved fluence: one pixel per cell, its plane drawn over the image; moving
  // the plane asks for another.
  await page.selectOption("#sliceField", "fluence");
  await page.waitForFunction(() => Number(document.getElementById("slice").dataset.slices || 0) >= 1 && document.getElementById("slice").naturalWidth > 0, null, { timeout: 30000 });
  const sl = await page.evaluate(() => ({ w: document.getElementById("slice").naturalWidth, h: document.getElementById("slice").naturalHeight,
    plane: document.querySelectorAll("#gizmo line.slice").length, hi: document.getElementById("sliceHi").textContent, url: document.getElementById("slice").dataset.url }));
  check("a slice of the fluence, its plane drawn", sl.w === 16 && sl.h === 16 && sl.plane === 4 && /e/.test(sl.hi), JSON.stringify(sl));
  await page.evaluate(() => { const r = document.getElementById("sliceIndex"); r.value = "2"; r.dispatchEvent(new Event("input")); });
  await page.waitForFunction(() => Number(document.getElementById("slice").dataset.slices) >= 2, null, { timeout: 30000 });
  const moved = await page.evaluate(() => document.getElementById("slice").dataset.url);
  check("moving the plane shows another slice", moved.includes("index=2") && moved !== sl.url, moved);
  await page.selectOption("#sliceField", "");

  // A shared URL opens the same scene and camera.
  const other = await browser.newPage({ viewport: { width: 900, height: 600 } });
  other.on("pageerror", (e) => errors.push(String(e)));
  await other.goto(shared);
  await nextImage(other, 0);
  const o = await shown(other);
  check("a shared URL opens its camera", o.camera === "top" && Math.abs(o.w / o.h - 1) < 0.02, JSON.stringify(o));
  await other.close();

  // Upload under a name: listed by name, solved, report and residual plot with axes.
  await page.evaluate(() => { document.getElementById("uploadBox").open = true; });
  await page.fill("#name", "second puff");
  await page.fill("#text", UPLOADED);
  await page.click("#upload");
  await page.waitForFunction(() => {
    const t = document.getElementById("status").textContent;
    return t.startsWith("second puff") && t.includes("state done");
  }, null, { timeout: 60000 });
  const listed = await page.evaluate(() => document.getElementById("scenes").selectedOptions[0].textContent);
  check("an upload is listed by its name and solved", listed.startsWith("second puff") && (await page.textContent("#status")).includes("iterations"), listed);
  const plot = await page.evaluate(() => ({ curve: document.querySelectorAll("#plot path.curve").length, axes: document.querySelectorAll("#plot line.axis").length, ticks: document.querySelectorAll("#plot text.tick").length }));
  check("residual plot with axes and ticks", plot.curve === 1 && plot.axes === 2 && plot.ticks >= 3, JSON.stringify(plot));
  await nextImage(page, s.n);
  check("no sun and sky controls without a sky", await page.evaluate(() => document.getElementById("lightBox").hidden));

  // A scene under a sky: its sun and sky controls; relighting solves a copy with the sun
  // moved, which the viewer then shows from the same camera.
  await page.fill("#name", "sky puff");
  await page.fill("#text", SKY);
  await page.click("#upload");
  await page.waitForFunction(() => document.getElementById("status").textContent.startsWith("sky puff") &&
    document.getElementById("status").textContent.includes("state done"), null, { timeout: 60000 });
  const light = await page.evaluate(() => ({ hidden: document.getElementById("lightBox").hidden,
    elevation: document.getElementById("sunElevation").value, text: document.getElementById("sunElevationText").textContent }));
  check("a sky scene shows its sun and sky", !light.hidden && light.elevation === "40" && light.text === "40°", JSON.stringify(light));
  s = await shown(page);
  await page.evaluate(() => { const r = document.getElementById("sunElevation"); r.value = "15"; r.dispatchEvent(new Event("input")); });
  await page.click("#relight");
  await page.waitForFunction(() => document.getElementById("status").textContent.startsWith("sky puff · sun 15°") &&
    document.getElementById("status").textContent.includes("state done"), null, { timeout: 60000 });
  const { scenes: all } = await (await fetch(`${base}/v1/scenes`)).json();
  const described = all.find((d) => (d.name || "").startsWith("sky puff · sun 15°")) || {};
  await page.waitForFunction((id) => (document.getElementById("view").dataset.url || "").includes(id) &&
    location.hash.includes(id), described.id || "none", { timeout: 60000 }).catch(() => {});
  const relit = await shown(page);
  const relitScene = await page.evaluate(() => document.getElementById("scenes").selectedOptions[0].textContent);
  check("relighting solves and shows a copy with the sun moved", relitScene.startsWith("sky puff · sun 15°") && relit.camera === "front" &&
    described.sky && described.sky.sun_elevation_degrees === 15 && relit.url.includes(described.id) && relit.hash.includes(described.id),
    JSON.stringify({ relitScene, relit, described }));

  if (screenshot) {
    // The README's picture: the relit sky scene's front view, its sun and sky controls.
    await page.evaluate(() => { document.getElementById("uploadBox").open = false; document.getElementById("side").scrollTop = 0; });
    await page.screenshot({ path: screenshot });
  }
  check("no script errors", errors.length === 0, errors.join("; "));
} catch (err) {
  check("run", false, String(err));
} finally {
  if (browser) await browser.close();
  server.kill("SIGINT");
  rmSync(cache, { recursive: true, force: true });
}
console.log(`${passed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);
