// The viewer's benchmark (targets: docs/notebook/viewer.md#against-the-targets; not a test): plays
// DB in headless Chromium at WIDTHxHEIGHT for SECONDS and prints, as JSON, the page's median frame
// rate over that time (one sample per second, measured by the page), the server's CPU time per
// frame served (getrusage of the clothdb process, all its threads, over the same time), and the
// page's load time (navigation start to the first cloth frame drawn). Optionally saves a
// screenshot.
//
//   node viewer/bench.mjs CLOTHDB DB [--seconds 10] [--width 1280] [--height 720] [--png FILE]
//                         [--batch N (frames per request; the page's default 8)] [--paused]
//                         [--assets DIR (another page folder, e.g. a copy of viewer/ to compare)]
//   node viewer/bench.mjs CLOTHDB DB --no-browser [--batch N] [--wait MS] [--frames 1200]
// The second form measures the server alone: one client asking for the frames the way the page
// does (N per request, each held MS ms; one connection per request, as the server closes each),
// server CPU per frame served.
import {launchBrowser, median, startViewer, stopViewer} from './driver.mjs';

const args = process.argv.slice(2);
const opt = (name, def) => {
  const i = args.indexOf(`--${name}`);
  return i >= 0 ? args[i + 1] : def;
};
const [clothdb, db] = args;
const seconds = Number(opt('seconds', 10));
const width = Number(opt('width', 1280)), height = Number(opt('height', 720));
const png = opt('png', '');
const batch = opt('batch', '');

const assets = opt('assets', '');
const viewer = await startViewer(clothdb, db, assets ? ['--assets', assets] : []);
if (args.includes('--no-browser')) {
  const n = Number(batch || 8), wait = Number(opt('wait', 0)), frames = Number(opt('frames', 1200));
  const stats = async () => (await fetch(viewer.url + 'api/stats')).json();
  // Not while the server decodes every clip into its cache at start (cli/cmd_view.cpp,
  // warm_cache): a page takes longer than that to load.
  while ((await stats()).warming) await new Promise((r) => setTimeout(r, 50));
  const s0 = await stats();
  for (let i = 0; i < frames / n; ++i)
    await (await fetch(viewer.url + `api/frames?dt=0.016667&n=${n}&wait=${wait}`)).arrayBuffer();
  const s1 = await stats();
  console.log(JSON.stringify({db, batch: n, wait_ms: wait, frames_served: s1.frames - s0.frames,
    server_cpu_ms_per_frame: 1e3 * (s1.cpu_seconds - s0.cpu_seconds) / (s1.frames - s0.frames)}));
  await stopViewer(viewer);
  process.exit(0);
}
const {context, close} = await launchBrowser(width, height);
try {
  const page = await context.newPage();
  await page.goto(viewer.url + (batch ? `?batch=${batch}` : ''));
  await page.waitForFunction(() => window.viewer && window.viewer.loadMs !== null, null,
                             {timeout: 60000});
  const loadMs = await page.evaluate(() => window.viewer.loadMs);
  const resources = await page.evaluate(() => performance.getEntriesByType('resource').map((r) =>
    [r.name.replace(location.origin, ''), Math.round(r.startTime), Math.round(r.duration)]));
  // --paused: the page draws without pulling frames (the browser's own ceiling for this page).
  if (args.includes('--paused')) await page.keyboard.press(' ');
  // Skip the first two seconds (shader compilation, the first clips decoded).
  await page.waitForTimeout(2000);
  const stats = async () => (await fetch(viewer.url + 'api/stats')).json();
  const s0 = await stats();
  const n0 = await page.evaluate(() => window.viewer.fpsSamples.length);
  await page.waitForTimeout(seconds * 1000);
  const s1 = await stats();
  const samples = (await page.evaluate(() => window.viewer.fpsSamples)).slice(n0);
  const cloth = (await page.evaluate(() => window.viewer.clothFpsSamples)).slice(n0);
  const frames = s1.frames - s0.frames;
  const state = await page.evaluate(() => ({errors: window.viewer.errors,
    runtimeUs: window.viewer.runtimeUs, drawn: window.viewer.framesDrawn}));
  if (png) await page.screenshot({path: png});
  console.log(JSON.stringify({db, width, height, seconds, batch: batch || 8, median_fps: median(samples),
    fps_samples: samples, median_cloth_fps: median(cloth), cloth_fps_samples: cloth,
    frames_served: frames,
    server_cpu_ms_per_frame: frames ? 1e3 * (s1.cpu_seconds - s0.cpu_seconds) / frames : null,
    runtime_us_per_frame: state.runtimeUs, load_ms: Math.round(loadMs), errors: state.errors,
    resources}, null, 1));
} finally {
  await close();
  await stopViewer(viewer);
}
