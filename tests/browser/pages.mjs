// Drives Trinocular's browser view in headless Chromium (Debian's, through playwright-core)
// against a live server, for tests/integration/browser.rs, which prepares the sessions,
// passes this script a JSON plan as its one argument and checks the JSON report it prints:
//
// plan: { base, chromium, screenshots, session, liveCapture, bigSession, sample: {image1..3,
//         calibration} }  (liveCapture: a file holding an AddCaptureRequest as JSON)
// report: { session: {...}, live: {...}, big: {...}, match: {...} }
//
// It measures and reports; the Rust test decides what passes.
import { readFileSync } from 'node:fs';
import { chromium } from 'playwright-core';

const plan = JSON.parse(process.argv[2]);
const report = {};

const browser = await chromium.launch({
  executablePath: plan.chromium,
  args: [
    '--no-sandbox',
    '--disable-gpu',
    '--disable-quic',
    '--no-first-run',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
    // WebGL on the CPU (SwiftShader), for the 3D views.
    '--use-angle=swiftshader',
    '--enable-unsafe-swiftshader',
  ],
});
const context = await browser.newContext({ viewport: { width: 1400, height: 1000 } });
const errors = [];

async function newPage() {
  const page = await context.newPage();
  page.on('pageerror', (e) => errors.push(`page error: ${e.message}`));
  page.on('console', (m) => m.type() === 'error' && errors.push(`console: ${m.text()}`));
  return page;
}

// Mean and spread of a canvas's pixels, and how many distinct colours it holds: a blank one has
// a spread near zero and one or two colours.
async function canvasStats(page, selector) {
  return page.$eval(selector, (canvas) => {
    let data;
    if (canvas.getContext('2d')) {
      data = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
    } else {
      return null;
    }
    let sum = 0;
    let sq = 0;
    const colours = new Set();
    const n = data.length / 4;
    for (let i = 0; i < data.length; i += 4) {
      const y = 0.299 * data[i] + 0.587 * data[i + 1] + 0.114 * data[i + 2];
      sum += y;
      sq += y * y;
      if (colours.size < 5000) colours.add((data[i] << 16) | (data[i + 1] << 8) | data[i + 2]);
    }
    const mean = sum / n;
    return { width: canvas.width, height: canvas.height, mean, spread: Math.sqrt(Math.max(0, sq / n - mean * mean)), colours: colours.size };
  });
}

async function sessionPage(id, screenshot) {
  const page = await newPage();
  const started = Date.now();
  await page.goto(`${plan.base}/sessions/${id}`);
  await page.waitForFunction(() => document.body.dataset.ready === 'true', null, { timeout: 30000 });
  const loadMs = Date.now() - started;
  const text = async (selector) => (await page.textContent(selector)).trim();
  const result = {
    loadMs,
    captures: Number(await text('#capture-count')),
    segments: Number(await text('#segment-count')),
    title: await text('#session-name'),
    topView: await canvasStats(page, '#top-view'),
    webgl: await page.$eval('#view-3d', (d) => Boolean(d.querySelector('canvas'))),
    downloadFormats: await page.$$eval('#download option', (o) => o.map((x) => x.value).filter(Boolean)),
  };
  if (screenshot) await page.screenshot({ path: `${plan.screenshots}/${screenshot}` });
  return { page, result };
}

// The session page: drawn, then live: a capture added from here appears on the page.
{
  const { page, result } = await sessionPage(plan.session, 'session.png');
  report.session = result;
  await page.waitForFunction(() => document.getElementById('live-state').textContent === 'live', null, { timeout: 10000 });
  const before = result.captures;
  const answer = await fetch(`${plan.base}/v1/sessions/${plan.session}/captures`, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: readFileSync(plan.liveCapture),
  });
  const answered = Date.now();
  const added = await answer.json();
  await page.waitForFunction((n) => Number(document.body.dataset.mapCaptures) === n, before + 1, { timeout: 10000, polling: 'raf' });
  report.live = {
    status: answer.status,
    captureIndex: added.captureIndex ?? 0,
    delayMs: Date.now() - answered,
    captures: Number((await page.textContent('#capture-count')).trim()),
    segments: Number((await page.textContent('#segment-count')).trim()),
  };
  // Pick a segment in the 3D view: the middle of the canvas often misses; try a grid of
  // points until the picked description appears.
  if (result.webgl) {
    const box = await page.locator('#view-3d canvas').boundingBox();
    let picked = '';
    for (let i = 1; i < 12 && !picked.startsWith('map segment'); i++) {
      for (let j = 1; j < 12 && !picked.startsWith('map segment'); j++) {
        await page.mouse.click(box.x + (box.width * i) / 12, box.y + (box.height * j) / 12);
        picked = (await page.textContent('#picked')).trim();
      }
    }
    report.live.picked = picked;
  }
  await page.screenshot({ path: `${plan.screenshots}/session-live.png` });
  await page.close();
}

// A session of many captures: how long the page takes to load and draw it.
if (plan.bigSession) {
  const { page, result } = await sessionPage(plan.bigSession, null);
  report.big = result;
  await page.close();
}

// The first page: the sessions listed; the Match page on uploaded files.
{
  const page = await newPage();
  await page.goto(`${plan.base}/`);
  await page.waitForSelector('#sessions-table, #no-sessions, .error', { timeout: 10000 });
  const rows = await page.$$eval('tr.session-row', (r) => r.map((x) => x.textContent));
  await page.setInputFiles('input[name=image1]', plan.sample.image1);
  await page.setInputFiles('input[name=image2]', plan.sample.image2);
  await page.setInputFiles('input[name=image3]', plan.sample.image3);
  await page.setInputFiles('input[name=calibration]', plan.sample.calibration);
  const response = page.waitForResponse((r) => r.url().endsWith('/v1/match'));
  await page.click('#match-button');
  const answer = await (await response).json();
  await page.waitForSelector('#match-facts, #match-result .error', { timeout: 30000 });
  const stats = [];
  for (let v = 1; v <= 3; v++) stats.push(await canvasStats(page, `#overlay-${v}`));
  report.match = {
    sessionRows: rows,
    answered3d: (answer.segments3d ?? []).length,
    facts: ((await page.textContent('#match-result p')) ?? '').trim(),
    captions: await page.$$eval('figcaption', (f) => f.map((x) => x.textContent)),
    overlays: stats,
    legend: await page.$$eval('.legend span', (s) => s.map((x) => x.textContent)),
    webgl: await page.$eval('#match-3d', (d) => Boolean(d.querySelector('canvas'))),
  };
  await page.screenshot({ path: `${plan.screenshots}/match.png`, fullPage: true });
  await page.close();
}

report.errors = errors;
await browser.close();
console.log(JSON.stringify(report));
