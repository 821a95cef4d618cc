// End-to-end test of the viewer page of `volrad serve` in a real headless Chromium:
// load the page, upload a small scene, watch its solve finish, drag to orbit, and check that
// a new full-resolution image arrived. Prints "N passed, M failed".
//
//   VOLRAD_BIN=target/debug/volrad CHROMIUM=/usr/bin/chromium node tests/e2e/viewer.mjs [screenshot.png]

import { spawn } from "node:child_process";
import { mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { chromium } from "playwright-core";

const bin = process.env.VOLRAD_BIN || "target/debug/volrad";
const browserPath = process.env.CHROMIUM || "/usr/bin/chromium";
const screenshot = process.argv[2] || null;
const port = 20000 + Math.floor(Math.random() * 20000);
const cache = mkdtempSync(join(tmpdir(), "volrad-e2e-"));

const SCENE = `[volume]
generator = { kind = "cloud", seed = 7 }
dims = [12, 12, 9]

[medium]
albedo = 0.95
phase = { kind = "isotropic" }

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[solve]
method = "zonal"

[render]
exposure = 4.0

[[camera]]
name = "front"
eye = [6.0, -18.0, 4.5]
target = [6.0, 6.0, 4.5]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 512
height = 384
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

const server = spawn(bin, ["--quiet", "serve", "--addr", `127.0.0.1:${port}`, "--cache", cache], { stdio: "inherit" });
let browser = null;
try {
  const base = `http://127.0.0.1:${port}`;
  check("server starts", await waitForServer(`${base}/v1/scenes`, 15000));
  browser = await chromium.launch({ executablePath: browserPath, args: ["--no-sandbox", "--headless=new"] });
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  await page.goto(base + "/");
  check("page loads", (await page.title()) === "volrad viewer");

  await page.fill("#text", SCENE);
  await page.click("#upload");
  await page.waitForFunction(() => document.getElementById("status").textContent.includes("state done"), null, { timeout: 30000 });
  check("solve finishes and the report shows", (await page.textContent("#status")).includes("iterations"));
  check("residual plot drawn", (await page.locator("#plot path").count()) === 1);

  await page.waitForFunction(() => {
    const img = document.getElementById("view");
    return img.dataset.resolution === "full" && Number(img.dataset.renders) >= 1 && img.naturalWidth === 512;
  }, null, { timeout: 20000 });
  const before = await page.evaluate(() => ({ n: Number(document.getElementById("view").dataset.renders), src: document.getElementById("view").src }));
  check("first full image arrives", before.n >= 1);

  const box = await page.locator("#view").boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) {
    await page.mouse.move(cx + i * 12, cy + i * 3);
    await new Promise((r) => setTimeout(r, 30));
  }
  await page.mouse.up();
  await page.waitForFunction((n) => {
    const img = document.getElementById("view");
    return Number(img.dataset.renders) > n + 1 && img.dataset.resolution === "full" && img.naturalWidth === 512;
  }, before.n, { timeout: 20000 });
  const after = await page.evaluate(() => ({ n: Number(document.getElementById("view").dataset.renders), src: document.getElementById("view").src }));
  check("dragging renders new images, ending at full resolution", after.n > before.n + 1 && after.src !== before.src, JSON.stringify({ before, after }));

  if (screenshot) await page.screenshot({ path: screenshot });
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
