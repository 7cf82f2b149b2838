// What the browser test (tests/browser/viewer_test.mjs) and the benchmark (viewer/bench.mjs)
// share: starting `clothdb view`, launching Debian's Chromium headless through playwright-core,
// and reading PNG screenshots (8-bit RGB/RGBA, no dependency beyond Node's zlib).
import {spawn} from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import zlib from 'node:zlib';

export const CHROMIUM = process.env.CLOTHDB_CHROMIUM || '/usr/bin/chromium';

// Starts `clothdb view DB --port 0 ...`; resolves with {url, proc, stderr()} once the first line
// (the URL) is printed, rejects if the process exits first.
export function startViewer(clothdb, db, extra = []) {
  return new Promise((resolve, reject) => {
    const proc = spawn(clothdb, ['view', db, '--port', '0', ...extra],
                       {stdio: ['ignore', 'pipe', 'pipe']});
    let out = '', err = '';
    proc.stderr.on('data', (d) => { err += d; });
    proc.stdout.on('data', (d) => {
      out += d;
      const line = out.split('\n');
      if (line.length > 1) resolve({url: line[0].trim(), proc, stderr: () => err});
    });
    proc.on('exit', (code) => reject(new Error(`clothdb view exited with ${code}: ${err}`)));
  });
}

// Stops the server with SIGINT (what Ctrl-C sends); resolves with its exit code.
export function stopViewer(viewer) {
  return new Promise((resolve) => {
    if (viewer.proc.exitCode !== null) return resolve(viewer.proc.exitCode);
    viewer.proc.removeAllListeners('exit');
    viewer.proc.on('exit', (code) => resolve(code));
    viewer.proc.kill('SIGINT');
  });
}

// Headless Chromium with the flags this machine needs (docs/guide/viewer.md): no sandbox (root),
// no GPU (WebGL through SwiftShader), nothing that reaches for the network.
export async function launchBrowser(width = 1280, height = 720) {
  // Imported here: the browser-less checks run without viewer/node_modules.
  const {chromium} = await import('playwright-core');
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'clothdb-chromium-'));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM,
    headless: true,
    viewport: {width, height},
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--enable-unsafe-swiftshader',
      '--disable-quic', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync'],
  });
  const close = async () => {
    await context.close();
    fs.rmSync(userDataDir, {recursive: true, force: true});
  };
  return {context, close};
}

// PNG -> {width, height, channels, data} for 8-bit, non-interlaced RGB or RGBA (what Chromium's
// screenshots are).
export function decodePng(buffer) {
  let pos = 8, width = 0, height = 0, colorType = 0;
  const idat = [];
  while (pos < buffer.length) {
    const len = buffer.readUInt32BE(pos);
    const type = buffer.toString('latin1', pos + 4, pos + 8);
    const data = buffer.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      colorType = data[9];
      if (data[8] !== 8 || data[12] !== 0 || (colorType !== 2 && colorType !== 6))
        throw new Error('PNG: only 8-bit non-interlaced RGB/RGBA is read here');
    } else if (type === 'IDAT') {
      idat.push(data);
    }
    pos += 12 + len;
  }
  const channels = colorType === 6 ? 4 : 3;
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const stride = width * channels;
  const out = Buffer.alloc(stride * height);
  for (let y = 0; y < height; ++y) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let x = 0; x < stride; ++x) {
      const a = x >= channels ? out[y * stride + x - channels] : 0;
      const b = y > 0 ? out[(y - 1) * stride + x] : 0;
      const c = x >= channels && y > 0 ? out[(y - 1) * stride + x - channels] : 0;
      let v = line[x];
      if (filter === 1) v += a;
      else if (filter === 2) v += b;
      else if (filter === 3) v += (a + b) >> 1;
      else if (filter === 4) {
        const p = a + b - c, pa = Math.abs(p - a), pb = Math.abs(p - b), pc = Math.abs(p - c);
        v += pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      }
      out[y * stride + x] = v & 255;
    }
  }
  return {width, height, channels, data: out};
}

export function pixel(img, x, y) {
  const i = (Math.round(y) * img.width + Math.round(x)) * img.channels;
  return [img.data[i], img.data[i + 1], img.data[i + 2]];
}

export const median = (xs) => {
  const s = [...xs].sort((a, b) => a - b);
  return s.length ? s[Math.floor(s.length / 2)] : NaN;
};
