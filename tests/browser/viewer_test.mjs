// `clothdb view` in a real browser (docs/guide/viewer.md#the-browser-test): Debian's headless
// Chromium (WebGL through SwiftShader) driven by playwright-core. Run by CTest through
// run_viewer_test.sh, which skips (exit 77) when Chromium, Node or the viewer's npm packages are
// missing.
//
//   node viewer_test.mjs CLOTHDB DEMO_DB WORK_DIR [server]
//
// `server`: only the checks that need no browser (bad databases, the missing-three.js page, bad
// requests, SIGINT): CTest's viewer_server, which runs wherever Node does.
//
// Each check names what a broken viewer would do to fail it.
import {spawnSync} from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import path from 'node:path';
import {fileURLToPath} from 'node:url';

import {decodePng, launchBrowser, pixel, startViewer, stopViewer} from '../../viewer/driver.mjs';

const [clothdb, db, work, mode] = process.argv.slice(2);
const noBrowser = mode === 'server';  // the checks that need no browser only
const viewerDir = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../../viewer');
const BACKGROUND = [0xdf, 0xe4, 0xea];  // viewer.js BACKGROUND
let failures = 0;
function check(ok, what) {
  console.log(`${ok ? 'ok  ' : 'FAIL'} ${what}`);
  if (!ok) ++failures;
}
const diff = (a, b) => Math.abs(a[0] - b[0]) + Math.abs(a[1] - b[1]) + Math.abs(a[2] - b[2]);

// A request written byte for byte (fetch would normalise "..", which is what is being tested).
function rawGet(url, target) {
  const {hostname, port} = new URL(url);
  return new Promise((resolve, reject) => {
    const s = net.connect(Number(port), hostname, () => {
      s.write(`GET ${target} HTTP/1.1\r\nHost: ${hostname}\r\nConnection: close\r\n\r\n`);
    });
    let data = '';
    s.on('data', (d) => { data += d; });
    s.on('end', () => resolve({status: Number(data.split(' ')[1]), text: data}));
    s.on('error', reject);
  });
}

fs.mkdirSync(work, {recursive: true});

// 1. A missing or bad database: non-zero exit before serving (no URL printed), naming the file.
for (const [bad, make] of [[path.join(work, 'missing.clothdb'), null],
  [path.join(work, 'not_a_db.clothdb'), 'this is not SQLite\n']]) {
  fs.rmSync(bad, {force: true});
  if (make) fs.writeFileSync(bad, make);
  const r = spawnSync(clothdb, ['view', bad, '--port', '0'], {encoding: 'utf8', timeout: 20000});
  check(r.status !== 0 && r.status !== null && r.stdout === '' && r.stderr.includes(bad),
        `bad database ${path.basename(bad)}: exit ${r.status}, stderr names it: ${r.stderr.trim()}`);
}

// 2. Without three.js the page says so (a folder with the page but no node_modules).
{
  const bare = path.join(work, 'bare_assets');
  fs.mkdirSync(bare, {recursive: true});
  fs.copyFileSync(path.join(viewerDir, 'index.html'), path.join(bare, 'index.html'));
  const v = await startViewer(clothdb, db, ['--assets', bare]);
  const r = await fetch(v.url);
  const text = await r.text();
  check(r.status === 503 && text.includes('three.js is missing'),
        `without three.js: GET / is ${r.status} with the "three.js is missing" page`);
  check(await stopViewer(v) === 0, 'SIGINT stops the server with exit 0');
}

// 2b. The page's module: the bundle (dist/viewer.js) while it is at least as new as viewer.js, else
// viewer.js itself (cli/cmd_view.cpp, page_module), so an edited page is never hidden by an old
// bundle.
{
  const page = path.join(work, 'bundle_assets');
  fs.mkdirSync(path.join(page, 'dist'), {recursive: true});
  for (const f of ['index.html', 'viewer.js', 'viewer.css'])
    fs.copyFileSync(path.join(viewerDir, f), path.join(page, f));
  const bundle = '// a bundle made after viewer.js\n';
  fs.writeFileSync(path.join(page, 'dist', 'viewer.js'), bundle);
  const at = (f, s) => fs.utimesSync(path.join(page, f), s, s);
  at('viewer.js', 1000);
  at('dist/viewer.js', 2000);
  const v = await startViewer(clothdb, db, ['--assets', page]);
  try {
    let text = await (await fetch(v.url + 'viewer.js')).text();
    check(text === bundle, 'GET /viewer.js is dist/viewer.js when it is newer than viewer.js');
    at('viewer.js', 3000);
    text = await (await fetch(v.url + 'viewer.js')).text();
    check(text.includes("from 'three'") && text !== bundle,
          'GET /viewer.js is viewer.js itself once viewer.js is newer than the bundle');
  } finally {
    check(await stopViewer(v) === 0, 'SIGINT stops the server with exit 0');
  }
  const stale = await startViewer(clothdb, db, ['--assets', page]);
  await stopViewer(stale);
  // 'exit' can come before the last of stderr is read.
  await new Promise((r) => stale.proc.stderr.closed ? r() : stale.proc.stderr.on('close', r));
  check(stale.stderr().includes('dist/viewer.js is missing or older than viewer.js'),
        `a server started with an old bundle says it serves viewer.js unbundled: ${stale.stderr()}`);
}

// 6. Bad requests: 4xx, nothing outside the served folders, and the server answers afterwards.
async function badRequests(viewer) {
  const secret = fs.readFileSync(path.join(viewerDir, 'package.json'), 'utf8').slice(0, 40);
  for (const target of ['/three/../../package.json', '/three/%2e%2e/%2e%2e/package.json',
    '/three/..%2f..%2fpackage.json', '/three/../../../../../../etc/passwd', '/../CMakeLists.txt',
    '/three/build/../../../viewer.js']) {
    const r = await rawGet(viewer.url, target);
    check(r.status >= 400 && r.status < 500 && !r.text.includes(secret) &&
          !r.text.includes('root:'), `GET ${target}: ${r.status}, no file outside served`);
  }
  const bad = [['GET', 'api/frame?dt=-1'], ['GET', 'api/frame?dt=1e308'], ['GET', 'api/frame?dt=nan'],
    ['GET', 'api/frames?n=99999999999999999999999'], ['GET', 'api/frames?n=0'],
    ['GET', 'api/frames?n=2&wait=-3'], ['GET', 'api/frames?wait=86400000'],
    ['GET', 'api/frames?dt=%ff%fe%c3'], ['GET', 'api/clips?by=%c3%28'],
    ['GET', 'api/clips?by=nonsense'], ['POST', 'api/control', '{"action": "next", "clip": 424242}'],
    ['POST', 'api/control', '{"action": "jump", "cloth_clip": -7}'],
    ['POST', 'api/control', '{"action": "jump", "cloth_clip": 1e300}'],
    ['POST', 'api/control', '{"action": "blend", "frames": 1e9}'],
    ['POST', 'api/control', '{not json'], ['POST', 'api/control', '"a string"'],
    ['POST', 'api/control', '{"action": "explode"}']];
  for (const [method, url, body] of bad) {
    const r = await fetch(viewer.url + url, {method, body});
    check(r.status >= 400 && r.status < 500, `${method} /${url} ${body || ''}: ${r.status}`);
  }
  const info = await fetch(viewer.url + 'api/info');
  check(info.status === 200 && viewer.proc.exitCode === null,
        'after the bad requests the server still answers');
}

const viewer = await startViewer(clothdb, db);
if (noBrowser) {
  // Without Chromium (run_viewer_test.sh server): the server alone.
  try {
    await badRequests(viewer);
  } finally {
    check(await stopViewer(viewer) === 0, 'SIGINT stops the server with exit 0');
  }
} else {
  const {context, close} = await launchBrowser(1280, 720);
  try {
    const page = await context.newPage();
    const pageErrors = [];
    page.on('pageerror', (e) => pageErrors.push(e.message));
    await page.goto(viewer.url);
    await page.waitForFunction(() => window.viewer && window.viewer.framesDrawn > 10, null,
                               {timeout: 60000});
    const st = () => page.evaluate(() => ({...window.viewer.frame, errors: window.viewer.errors,
      clothFrames: window.viewer.clothFrames, fpsSamples: window.viewer.fpsSamples}));
    check((await st()).errors.length === 0 && pageErrors.length === 0,
          `page loads and plays without errors (${[...(await st()).errors, ...pageErrors]})`);

    // 3. The cloth is drawn: screen pixels at the cloth's projected vertices differ from the
    // background, and the same pixels are background once the cloth is hidden (so it is the cloth,
    // not a panel or the floor, that made them differ). Paused, so both shots show one pose.
    await page.keyboard.press(' ');
    await page.waitForTimeout(300);
    const points = await page.evaluate(() => {
      const panels = [...document.querySelectorAll('.panel')].map((e) => e.getBoundingClientRect());
      return window.viewer.clothScreenPoints(3).filter(([x, y]) => x > 2 && y > 2 &&
          x < innerWidth - 2 && y < innerHeight - 2 &&
          !panels.some((r) => x >= r.left - 2 && x <= r.right + 2 && y >= r.top - 2 &&
                              y <= r.bottom + 2));
    });
    const shown = decodePng(await page.screenshot());
    await page.evaluate(() => window.viewer.setClothVisible(false));
    await page.waitForTimeout(300);
    const hidden = decodePng(await page.screenshot());
    await page.evaluate(() => window.viewer.setClothVisible(true));
    const drawn = points.filter((p) => diff(pixel(shown, p[0], p[1]), BACKGROUND) > 30).length;
    const bare = points.filter((p) => diff(pixel(hidden, p[0], p[1]), BACKGROUND) <= 30).length;
    check(points.length >= 20 && drawn >= 0.9 * points.length,
          `cloth drawn: ${drawn} of ${points.length} cloth pixels differ from the background`);
    check(bare >= 0.8 * points.length,
          `cloth hidden: ${bare} of ${points.length} of those pixels are background`);
    await page.keyboard.press(' ');

    // 4. The frame rate the page measures is reported in the overlay.
    await page.waitForFunction(() => window.viewer.fpsSamples.length >= 2, null, {timeout: 30000});
    const fpsText = await page.textContent('#fps');
    const fps = Number((fpsText.match(/(\d+) FPS/) || [])[1]);
    check(fps > 0, `overlay reports the measured frame rate: "${fpsText}"`);

    // 5. Choosing the next clip at a node changes the clip that plays. With the random walk off the
    // player takes the lowest-id successor, so choosing the highest-id one is seen only if the
    // choice reached the player. Twice, at two nodes.
    await page.click('#random');  // on at load: off
    // Choose right after a node: the server plays up to ~11 frames ahead of the picture, so a choice
    // in a clip's last frames is for the node after (docs/guide/viewer.md).
    const start = await st();
    await page.waitForFunction((n) => window.viewer.frame.transitions > n, start.transitions,
                               {timeout: 30000});
    for (let round = 0; round < 2; ++round) {
      const before = await st();
      const choices = before.successors;
      if (choices.length < 2) {
        check(false, `primary clip ${before.primary_clip} has ${choices.length} successors: the ` +
              'test database needs nodes with two');
        break;
      }
      const chosen = Math.max(...choices);
      await page.click(`#next-buttons button[data-clip="${chosen}"]`);
      // The next node: transitions counts nodes passed (a clip may follow itself).
      await page.waitForFunction((n) => window.viewer.frame.transitions > n, before.transitions,
                                 {timeout: 30000});
      const after = await st();
      check(after.primary_clip === chosen,
            `at the end of primary clip ${before.primary_clip} the chosen ${chosen} plays ` +
            `(not the default ${Math.min(...choices)}): now ${after.primary_clip}`);
    }

    await badRequests(viewer);
    const frames = (await st()).clothFrames;
    await page.waitForFunction((n) => window.viewer.clothFrames > n + 10, frames, {timeout: 20000});
    check(true, 'after the bad requests the page still plays');
  } finally {
    await close();
    check(await stopViewer(viewer) === 0, 'SIGINT stops the server with exit 0');
  }
}
console.log(failures ? `${failures} check(s) failed` : 'all checks passed');
process.exit(failures ? 1 : 0);
