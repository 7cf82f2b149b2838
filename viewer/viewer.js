// The page of `clothdb view` (cli/cmd_view.cpp): draws the frames the server's runtime player
// produces, with the character's body capsules, and sends the controls back.
//
// Frames: batches of `GET /api/frames?dt=...&n=...&wait=...`, one request in flight at a time
// (cli/cmd_view.cpp: how frames reach the page); dt is the page's frame interval (times the
// slow-motion factor), so the cloth plays in real time whatever the frame rate. The cloth is the
// render mesh (the artist's vertices, seam copies split) with the normals the runtime computed,
// quantised on the wire (int16 positions, int8 normals) and turned back into floats here.
import * as THREE from 'three';
import {OrbitControls} from 'three/addons/controls/OrbitControls.js';

const SLOW = 0.25;       // slow-motion factor
const MAX_STEP = 0.1;    // s: a longer gap (a hidden tab, a stall) plays as this
// Frames per request (cli/cmd_view.cpp: how frames reach the page); ?batch=N overrides it.
const BATCH = Math.max(1, Math.min(16, Number(new URLSearchParams(location.search).get('batch')) || 16));
const BACKGROUND = 0xdfe4ea;
const OVERLAY_INTERVAL_MS = 100;  // the overlay's text is rewritten at most this often
let lastOverlay = 0;

// Everything the page measures and shows; also read by the browser test and the benchmark
// (tests/browser/, viewer/bench.mjs).
const state = {
  info: null,
  frame: null,          // the last frame's header (the player's state)
  paused: false,
  slow: false,
  random: true,
  stepPending: false,
  inflight: false,
  lastTick: 0,          // the previous animation frame's time
  interval: 0,          // s between animation frames, smoothed
  framesDrawn: 0,       // animation frames drawn
  clothFrames: 0,       // frames received from the server
  fps: 0,               // animation frames drawn in the last whole second
  fpsSamples: [],       // one per second since the first cloth frame
  clothFps: 0,          // new cloth frames shown in the last whole second
  clothFpsSamples: [],
  loadMs: null,         // navigation start -> first cloth frame drawn
  runtimeUs: 0,         // server: advance + positions, smoothed
  errors: [],
  clipRows: [],
  setClothVisible: (visible) => { cloth.visible = visible; },
  // Screen pixels (CSS px) of every k-th cloth vertex, for the test's screenshot check.
  clothScreenPoints: (k = 7) => {
    const out = [];
    const p = geometry.attributes.position;
    const v = new THREE.Vector3();
    const w = renderer.domElement.clientWidth, h = renderer.domElement.clientHeight;
    for (let i = 0; i < p.count; i += k) {
      v.fromBufferAttribute(p, i).project(camera);
      if (Math.abs(v.x) < 1 && Math.abs(v.y) < 1 && v.z < 1)
        out.push([(v.x + 1) / 2 * w, (1 - v.y) / 2 * h]);
    }
    return out;
  },
};
window.viewer = state;

const $ = (id) => document.getElementById(id);
function showError(message) {
  state.errors.push(message);
  $('error').hidden = false;
  $('error').textContent = message;
}

// `response`: a request already made (index.html starts the first ones), else fetch(url, options).
async function getJson(url, options, response = null) {
  const r = await (response || fetch(url, options));
  const body = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(`${url}: ${r.status} ${body.error || r.statusText}`);
  return body;
}
const control = (body) =>
  getJson('/api/control', {method: 'POST', body: JSON.stringify(body)}).catch((e) =>
    showError(e.message));

// ---- scene ------------------------------------------------------------------------------------

const renderer = new THREE.WebGLRenderer({canvas: $('view'), antialias: false});
renderer.setPixelRatio(1);
const scene = new THREE.Scene();
scene.background = new THREE.Color(BACKGROUND);
const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
const orbit = new OrbitControls(camera, renderer.domElement);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8070, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.8);
sun.position.set(1.5, 3, 2);
scene.add(sun);

const geometry = new THREE.BufferGeometry();
const cloth = new THREE.Mesh(
    geometry, new THREE.MeshLambertMaterial({color: 0x2f6fb5, side: THREE.DoubleSide}));
cloth.frustumCulled = false;
scene.add(cloth);
const body = new THREE.Group();
scene.add(body);
const bodyMaterial = new THREE.MeshLambertMaterial({color: 0xd8b08c});
let grid = null;

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

// Frames the camera on the cloth (and floor) once, at the first frame.
function frameCamera(positions) {
  const box = new THREE.Box3().setFromArray(positions);
  const center = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3()).length() || 1;
  const height = Math.max(size, 1.8);  // a character is about this tall around its cloth
  // The cloth hangs from the hips: the legs below it are in view too.
  const lift = state.info.body ? -0.1 * height : 0;
  orbit.target.set(center.x, center.y + lift, center.z);
  camera.position.set(center.x + 0.7 * height, center.y + lift + 0.2 * height,
                      center.z + 1.3 * height);
  orbit.update();
  grid = new THREE.GridHelper(4, 16, 0x9aa4ae, 0xbfc7cf);
  grid.position.set(center.x, box.min.y - (state.info.body ? 0.6 : 0.05), center.z);
  scene.add(grid);
}

// ---- body capsules ----------------------------------------------------------------------------

// The capsules come with each frame: 7 floats each (a, b, radius), character space.
const up = new THREE.Vector3(0, 1, 0), dir = new THREE.Vector3();
function drawBody(caps) {
  const n = caps.length / 7;
  if (!n) return;
  if (body.children.length !== n) {
    if (caps[6] <= 0) return;  // no poses for this clip
    for (let i = 0; i < n; ++i) {
      const c = caps.subarray(7 * i, 7 * i + 7);
      const length = Math.hypot(c[3] - c[0], c[4] - c[1], c[5] - c[2]);
      body.add(new THREE.Mesh(new THREE.CapsuleGeometry(c[6], length, 4, 10), bodyMaterial));
    }
  }
  for (let i = 0; i < n; ++i) {
    const c = caps.subarray(7 * i, 7 * i + 7);
    const mesh = body.children[i];
    mesh.visible = c[6] > 0;
    mesh.position.set((c[0] + c[3]) / 2, (c[1] + c[4]) / 2, (c[2] + c[5]) / 2);
    dir.set(c[3] - c[0], c[4] - c[1], c[5] - c[2]);
    if (dir.lengthSq() > 0) mesh.quaternion.setFromUnitVectors(up, dir.normalize());
  }
}

// ---- frames -----------------------------------------------------------------------------------

function clipName(id) {
  const c = state.info.clips.find((c) => c.id === id);
  return c ? `${c.name} (${id})` : String(id);
}
function frameRate(id) {
  const c = state.info.clips.find((c) => c.id === id);
  return c && c.frame_rate > 0 ? c.frame_rate : 30;
}

// Frames received and not yet shown, oldest first.
const queue = [];

// `response`: the request already made for these frames (the first one, from index.html).
async function request(dt, n, wait, response = null) {
  state.inflight = true;
  try {
    const r =
        await (response || fetch(`/api/frames?dt=${dt.toFixed(6)}&n=${n}&wait=${Math.round(wait)}`));
    if (!r.ok) throw new Error(`/api/frames: ${r.status} ${await r.text()}`);
    const states = JSON.parse(r.headers.get('X-Clothdb-Frames'));
    const all = await r.arrayBuffer();
    const size = state.info.frame_bytes, m = 3 * state.info.vertices, c = 7 * state.info.capsules;
    if (all.byteLength !== size * states.length)
      throw new Error(`/api/frames: ${all.byteLength} bytes for ${states.length} frames`);
    // One frame on the wire (cli/cmd_view.cpp, wire_frame_bytes): origin and step, capsules
    // (float32), positions (int16 over the frame's box), normals (int8, times 127).
    states.forEach((f, k) => {
      const at = k * size, q = at + 4 * (4 + c);
      queue.push({
        f,
        head: new Float32Array(all, at, 4),
        capsules: new Float32Array(all, at + 16, c),
        positions: new Int16Array(all, q, m),
        normals: new Int8Array(all, q + 2 * m, m),
      });
    });
  } catch (e) {
    showError(`${e.message} (is clothdb view still running?)`);
    setPaused(true);
  } finally {
    state.inflight = false;
  }
  if (!state.paused) ask();
}

// While playing, the next batch is always asked for, and the server holds the answer until the
// queue will be down to three frames, less 10 ms (cli/cmd_view.cpp: how frames reach the page). dt
// is the page's own frame interval (smoothed), so the cloth plays in real time whatever the frame
// rate; slow motion scales it.
function ask() {
  if (state.inflight || state.paused) return;
  if (!state.frame && !queue.length) return request(0, 1, 0);
  const interval = state.interval || 1 / 60;
  const wait = Math.max(0, Math.min(500, (queue.length - 3) * interval * 1000 - 10));
  request(interval * (state.slow ? SLOW : 1), BATCH, wait);
}

// At every animation frame: show the next queued frame (or, for a single step while paused, the
// next one received or one stored frame of the clip).
function pull(now) {
  if (state.lastTick) {
    const interval = Math.min(MAX_STEP, Math.max(1 / 240, (now - state.lastTick) / 1000));
    state.interval = state.interval ? 0.9 * state.interval + 0.1 * interval : interval;
  }
  state.lastTick = now;
  if (state.stepPending) {
    state.stepPending = false;
    if (queue.length) applyFrame(queue.shift());
    else if (!state.inflight)
      request(state.frame ? 1 / frameRate(state.frame.primary_clip) : 0, 1, 0).then(() => {
        if (queue.length) applyFrame(queue.shift());
      });
    return;
  }
  if (state.paused) return;
  if (queue.length) applyFrame(queue.shift());
  ask();
}

// After a jump the queued frames are from before it.
function flush() { queue.length = 0; }

// A frame's quantised positions and normals into the float arrays three.js draws.
function dequantise(head, q, qn, p, nr) {
  const ox = head[0], oy = head[1], oz = head[2], step = head[3], s = 1 / 127;
  for (let i = 0; i < q.length; i += 3) {
    p[i] = ox + step * q[i];
    p[i + 1] = oy + step * q[i + 1];
    p[i + 2] = oz + step * q[i + 2];
  }
  for (let i = 0; i < qn.length; ++i) nr[i] = s * qn[i];
}

function applyFrame({f, head, positions, normals, capsules}) {
  const attr = geometry.attributes.position;
  if (!attr) {
    const p = new Float32Array(positions.length), nr = new Float32Array(normals.length);
    dequantise(head, positions, normals, p, nr);
    geometry.setAttribute('position', new THREE.BufferAttribute(p, 3));
    geometry.setAttribute('normal', new THREE.BufferAttribute(nr, 3));
    frameCamera(p);
  } else {
    dequantise(head, positions, normals, attr.array, geometry.attributes.normal.array);
    attr.needsUpdate = true;
    geometry.attributes.normal.needsUpdate = true;
  }
  const changed = !state.frame || state.frame.primary_clip !== f.primary_clip ||
      state.frame.next_clip !== f.next_clip;
  state.frame = f;
  ++state.clothFrames;
  state.runtimeUs = state.runtimeUs ? 0.95 * state.runtimeUs + 0.05 * f.runtime_us : f.runtime_us;
  if (f.error) showError(`runtime: ${f.error}`);
  if (changed) nextButtons(f);
  drawBody(capsules);
  // The overlay's text at most ten times a second, and at once when the clips change: rewriting
  // it every frame made the browser lay out and paint it 60 times a second, in software here,
  // beside the cloth (54 -> 58 FPS on the demo, docs/notebook/viewer.md).
  const now = performance.now();
  if (changed || now - lastOverlay >= OVERLAY_INTERVAL_MS) {
    lastOverlay = now;
    overlay();
  }
}

function overlay() {
  const f = state.frame;
  if (!f) return;
  const clip = state.info.clips.find((c) => c.id === f.primary_clip);
  $('primary').textContent =
      `${clipName(f.primary_clip)} frame ${f.primary_frame.toFixed(1)} / ${clip ? clip.frames - 1 : '?'}`;
  $('cloth').textContent = `${f.cloth_clip || 'none'} from state ${f.cloth_state}` +
      (f.fallback ? ', fallback' : '') + (f.holding ? ', HOLDING last good pose' : '');
  $('next').textContent = f.next_clip ? clipName(f.next_clip) : 'not decided';
  $('blend').textContent = f.blending ? `in progress, weight ${f.blend_weight.toFixed(2)}`
                                      : `none (blend frames ${$('blend-frames').value})`;
  $('runtime').textContent =
      `${state.runtimeUs.toFixed(1)} µs per frame, ${f.stalls} stalls, ${f.transitions} transitions`;
  $('fps').textContent = `${state.fps} FPS, ${state.clothFps} cloth frames/s` +
      (state.loadMs !== null ? `, loaded in ${Math.round(state.loadMs)} ms` : '');
  $('mode').textContent = (state.paused ? 'paused' : state.slow ? `slow x${SLOW}` : 'normal') +
      (state.random ? ', random walk' : '');
  for (const row of document.querySelectorAll('#clip-table tr.clip'))
    row.classList.toggle('playing', Number(row.dataset.clip) === f.cloth_clip);
}

function nextButtons(f) {
  const div = $('next-buttons');
  div.replaceChildren();
  f.successors.forEach((id, i) => {
    const b = document.createElement('button');
    b.textContent = `${i + 1}: ${clipName(id)}`;
    b.dataset.clip = id;
    b.classList.toggle('chosen', id === f.next_clip);
    b.onclick = () => chooseNext(id);
    div.appendChild(b);
  });
}

async function chooseNext(id) {
  const f = await control({action: 'next', clip: id});
  if (f) {
    state.frame = {...state.frame, next_clip: f.next_clip};
    nextButtons(state.frame);
  }
}

// ---- controls ---------------------------------------------------------------------------------

function setPaused(paused) {
  state.paused = paused;
  if (!paused) ask();
  $('pause').classList.toggle('on', paused);
  overlay();
}
function setSlow(slow) {
  state.slow = slow;
  $('slow').classList.toggle('on', slow);
  overlay();
}
async function setRandom(random) {
  state.random = random;
  $('random').classList.toggle('on', random);
  await control({action: 'random', enabled: random, seed: 1});
  overlay();
}
function step() {
  setPaused(true);
  state.stepPending = true;
}
function setBlend(frames) {
  frames = Math.max(0, Math.min(600, Math.round(frames)));
  $('blend-frames').value = frames;
  control({action: 'blend', frames});
}

$('pause').onclick = () => setPaused(!state.paused);
$('step').onclick = step;
$('slow').onclick = () => setSlow(!state.slow);
$('random').onclick = () => setRandom(!state.random);
$('blend-frames').onchange = (e) => setBlend(Number(e.target.value));
window.addEventListener('keydown', (e) => {
  if (e.target.tagName === 'INPUT' || e.target.tagName === 'SELECT') return;
  if (e.key === ' ') setPaused(!state.paused);
  else if (e.key === '.') step();
  else if (e.key === 's' || e.key === 'S') setSlow(!state.slow);
  else if (e.key === 'r' || e.key === 'R') setRandom(!state.random);
  else if (e.key === '[') setBlend(Number($('blend-frames').value) - 1);
  else if (e.key === ']') setBlend(Number($('blend-frames').value) + 1);
  else if (e.key >= '1' && e.key <= '9' && state.frame) {
    const id = state.frame.successors[Number(e.key) - 1];
    if (id !== undefined) chooseNext(id);
  } else return;
  e.preventDefault();
});

// ---- clip table (clothdb clips list) ----------------------------------------------------------

async function loadClips() {
  const by = $('metric').value;
  const table = await getJson(`/api/clips?by=${encodeURIComponent(by)}`).catch((e) => {
    showError(e.message);
    return null;
  });
  if (!table) return;
  state.clipRows = table.clips;
  const metrics = state.info.metrics;
  const head = ['id', 'primary', 'frames', ...metrics.map((m) => m.name)];
  const t = $('clip-table');
  t.replaceChildren();
  const hr = t.insertRow();
  head.forEach((h) => {
    const th = document.createElement('th');
    th.textContent = h;
    th.classList.toggle('sorted', h === by);
    hr.appendChild(th);
  });
  for (const row of table.clips) {
    const tr = t.insertRow();
    tr.className = 'clip';
    tr.dataset.clip = row.id;
    const cells = [row.id, row.primary_clip, row.frames,
      ...metrics.map((m) => row[m.key] === null ? '?' : Number(row[m.key]).toFixed(2))];
    cells.forEach((c) => { tr.insertCell().textContent = c; });
    tr.onclick = () => control({action: 'jump', cloth_clip: row.id}).then(flush);
  }
  overlay();
}

// ---- start ------------------------------------------------------------------------------------

let secondStart = 0, secondFrames = 0, secondCloth = 0;
function animate(t) {
  requestAnimationFrame(animate);
  pull(t);
  renderer.render(scene, camera);
  if (!state.clothFrames) return;
  ++state.framesDrawn;
  if (state.loadMs === null) {
    state.loadMs = performance.now();
    renderer.domElement.style.visibility = 'visible';  // index.html: hidden until now
    loadClips();  // after the first cloth frame: the table is not needed to see the cloth
  }
  if (!secondStart) {
    secondStart = t;
    secondCloth = state.clothFrames;
  }
  ++secondFrames;
  if (t - secondStart >= 1000) {
    state.fps = Math.round(secondFrames * 1000 / (t - secondStart));
    state.fpsSamples.push(state.fps);
    state.clothFps = Math.round((state.clothFrames - secondCloth) * 1000 / (t - secondStart));
    state.clothFpsSamples.push(state.clothFps);
    secondCloth = state.clothFrames;
    secondStart = t;
    secondFrames = 0;
    overlay();
  }
}

async function main() {
  // Made by index.html while three.js loaded: the random walk on, the info, the triangles, the
  // first frame.
  const start = window.clothdbStart;
  state.info = await getJson('/api/info', undefined, start.info);
  document.title = `clothdb view: ${state.info.file}`;
  $('title').textContent = `${state.info.file}: ${state.info.vertices} vertices, ` +
      `${state.info.triangles} triangles`;
  $('body-note').textContent = state.info.body ? '' : state.info.body_note;
  const tris = new Uint32Array(await (await start.triangles).arrayBuffer());
  geometry.setIndex(new THREE.BufferAttribute(tris, 1));
  for (const m of state.info.metrics) $('metric').add(new Option(m.name, m.name));
  $('metric').onchange = loadClips;
  $('random').classList.add('on');  // state.random is true from the start
  await getJson('/api/control', undefined, start.random);
  // The first frame before the first draw: the first draw is then the cloth's, not an empty
  // scene's (each first draw costs a few hundred ms in SwiftShader, docs/notebook/viewer.md).
  await request(0, 1, 0, start.frame);
  requestAnimationFrame(animate);
}
main().catch((e) => showError(e.message));
