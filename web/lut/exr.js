// OpenEXR decoder for the texture bundle's files (docs/lut.md): single-part scan-line images,
// uncompressed, ZIPS or ZIP compressed, HALF or FLOAT channels — the subset `skybake lut` and
// GET /v1/lut/files/{key} write (OpenEXR file layout, "OpenEXR File Layout" document). Other
// files (tiles, multi-part, deep, PIZ/PXR24/B44/DWA) are refused with an error naming what is
// unsupported. Inflate is the browser's own DecompressionStream ("deflate" = the zlib stream
// EXR's ZIP compression writes); no third-party code.
"use strict";

/** Decodes an EXR file: { width, height, channels: { name: Float32Array (row 0 first) },
 *  halfBits: { name: Uint16Array } for HALF channels (to upload as HALF_FLOAT unchanged) }. */
async function decodeExr(buffer) {
  const bytes = new Uint8Array(buffer);
  const view = new DataView(buffer);
  const fail = (what) => { throw new Error(`EXR: ${what}`); };
  if (bytes.length < 8 || view.getUint32(0, true) !== 20000630) fail("not an OpenEXR file");
  const version = view.getUint32(4, true);
  if ((version & 0xff) !== 2) fail(`version ${version & 0xff} unsupported`);
  if (version & 0x200) fail("tiled files are not supported");
  if (version & 0x1800) fail("deep or multi-part files are not supported");
  let pos = 8;
  const cstring = () => {
    const start = pos;
    while (pos < bytes.length && bytes[pos] !== 0) pos++;
    if (pos >= bytes.length) fail("truncated header");
    const s = new TextDecoder().decode(bytes.subarray(start, pos));
    pos++;
    return s;
  };
  const header = {};
  for (;;) {
    const name = cstring();
    if (name === "") break;
    const type = cstring();
    const size = view.getInt32(pos, true);
    pos += 4;
    if (size < 0 || pos + size > bytes.length) fail(`attribute ${name} overruns the file`);
    header[name] = { type, start: pos, size };
    pos += size;
  }
  for (const need of ["channels", "compression", "dataWindow", "lineOrder"]) {
    if (!header[need]) fail(`header has no ${need}`);
  }
  // Channel list: name, pixel type (1 HALF, 2 FLOAT), pLinear, reserved, x/y sampling.
  const channels = [];
  {
    let p = header.channels.start;
    const end = p + header.channels.size;
    while (p < end && bytes[p] !== 0) {
      const s = p;
      while (bytes[p] !== 0) p++;
      const name = new TextDecoder().decode(bytes.subarray(s, p));
      p++;
      const type = view.getInt32(p, true);
      const xs = view.getInt32(p + 8, true);
      const ys = view.getInt32(p + 12, true);
      p += 16;
      if (type !== 1 && type !== 2) fail(`channel ${name}: pixel type ${type} unsupported`);
      if (xs !== 1 || ys !== 1) fail(`channel ${name}: subsampling unsupported`);
      channels.push({ name, type, size: type === 1 ? 2 : 4 });
    }
  }
  const compression = bytes[header.compression.start];
  const linesPerBlock = { 0: 1, 2: 1, 3: 16 }[compression];
  if (linesPerBlock === undefined) fail(`compression ${compression} unsupported (NONE, ZIPS, ZIP only)`);
  const dw = header.dataWindow.start;
  const xMin = view.getInt32(dw, true), yMin = view.getInt32(dw + 4, true);
  const width = view.getInt32(dw + 8, true) - xMin + 1;
  const height = view.getInt32(dw + 12, true) - yMin + 1;
  if (!(width > 0 && height > 0 && width * height <= 1 << 26)) fail("bad data window");
  const pixelBytes = channels.reduce((s, c) => s + c.size, 0);
  const blocks = Math.ceil(height / linesPerBlock);
  const out = {}, halfBits = {};
  for (const c of channels) {
    out[c.name] = new Float32Array(width * height);
    if (c.type === 1) halfBits[c.name] = new Uint16Array(width * height);
  }
  const jobs = [];
  for (let b = 0; b < blocks; b++) {
    const offset = Number(view.getBigUint64(pos + 8 * b, true));
    if (offset + 8 > bytes.length) fail(`block ${b} offset beyond the file`);
    const y = view.getInt32(offset, true) - yMin;
    const size = view.getInt32(offset + 4, true);
    if (y < 0 || y >= height || size < 0 || offset + 8 + size > bytes.length) fail(`block ${b} is corrupt`);
    const lines = Math.min(linesPerBlock, height - y);
    const expected = lines * width * pixelBytes;
    const data = bytes.subarray(offset + 8, offset + 8 + size);
    jobs.push((async () => {
      // A block is stored raw when compressing did not make it smaller.
      const raw = compression === 0 || size >= expected ? data : await unzip(data, expected);
      if (raw.length !== expected) fail(`block ${b}: ${raw.length} bytes for ${expected}`);
      const dv = new DataView(raw.buffer, raw.byteOffset, raw.byteLength);
      let p = 0;
      for (let l = 0; l < lines; l++) {
        const row = (y + l) * width;
        for (const c of channels) {
          const dst = out[c.name];
          if (c.type === 1) {
            const bits = halfBits[c.name];
            for (let x = 0; x < width; x++, p += 2) {
              const h = dv.getUint16(p, true);
              bits[row + x] = h;
              dst[row + x] = halfToFloat(h);
            }
          } else {
            for (let x = 0; x < width; x++, p += 4) dst[row + x] = dv.getFloat32(p, true);
          }
        }
      }
    })());
  }
  await Promise.all(jobs);
  return { width, height, channels: out, halfBits };
}

/** EXR's ZIP: zlib inflate, then undo the byte predictor and the two-half interleaving. */
async function unzip(data, expected) {
  const stream = new Blob([data]).stream().pipeThrough(new DecompressionStream("deflate"));
  const t = new Uint8Array(await new Response(stream).arrayBuffer());
  if (t.length !== expected) throw new Error(`EXR: inflated ${t.length} bytes for ${expected}`);
  for (let i = 1; i < t.length; i++) t[i] = (t[i - 1] + t[i] - 128) & 0xff;
  const out = new Uint8Array(t.length);
  const half = (t.length + 1) >> 1;
  for (let i = 0, j = 0; i < t.length; i += 2, j++) {
    out[i] = t[j];
    if (i + 1 < t.length) out[i + 1] = t[half + j];
  }
  return out;
}

/** IEEE 754 binary16 to a number. */
function halfToFloat(h) {
  const s = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 0x1f;
  const m = h & 0x3ff;
  if (e === 0) return s * m * 2 ** -24;
  if (e === 31) return m ? NaN : s * Infinity;
  return s * (1 + m / 1024) * 2 ** (e - 15);
}
