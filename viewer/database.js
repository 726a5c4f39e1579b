// The .btfdb format of docs/format.md, read in the browser: the head (header, version records,
// section table), the shape of each section, its stored bytes decoded (encodings 0, 1 and 2) into
// the values of its fields, and the scalar quantization undone exactly as pipeline/format/packing.cpp
// does (double precision, rounded once to f32).
import { FieldDecoder, CorruptSection } from './range_coder.js';
import { decompress as zstdDecompress } from './fzstd.js';

export const kHeaderBytes = 56;
export const CODEBOOKS = ['P1', 'C', 'I1', 'I2', 'P2', 'M', 'P3', 'P4'];
const kVersionRecordBytes = 52;

const u64 = (view, at) => view.getUint32(at, true) + view.getUint32(at + 4, true) * 2 ** 32;

// CRC-64/XZ (docs/format.md "Conventions") in two 32-bit halves: the reflected polynomial
// 0xC96C5795D7870F42, initial value and final xor all ones. Returned as 16 hex digits.
const kCrcTable = (() => {
  const table = { lo: new Uint32Array(256), hi: new Uint32Array(256) };
  for (let i = 0; i < 256; ++i) {
    let lo = i, hi = 0;
    for (let k = 0; k < 8; ++k) {
      const bit = lo & 1;
      lo = ((lo >>> 1) | (hi << 31)) >>> 0;
      hi >>>= 1;
      if (bit) {
        lo = (lo ^ 0xd7870f42) >>> 0;
        hi = (hi ^ 0xc96c5795) >>> 0;
      }
    }
    table.lo[i] = lo;
    table.hi[i] = hi;
  }
  return table;
})();

export function crc64(bytes) {
  let lo = 0xffffffff, hi = 0xffffffff;
  for (let k = 0; k < bytes.length; ++k) {
    const i = (lo ^ bytes[k]) & 0xff;
    lo = (((lo >>> 8) | (hi << 24)) ^ kCrcTable.lo[i]) >>> 0;
    hi = ((hi >>> 8) ^ kCrcTable.hi[i]) >>> 0;
  }
  const hex = (v) => ((v ^ 0xffffffff) >>> 0).toString(16).padStart(8, '0');
  return hex(hi) + hex(lo);
}
const hex64 = (view, at) => view.getUint32(at + 4, true).toString(16).padStart(8, '0') + view.getUint32(at, true).toString(16).padStart(8, '0');

// head_length from the first 56 bytes.
export function parseHeader(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const magic = new TextDecoder().decode(bytes.subarray(0, 8));
  if (magic !== 'BTFVQDB1') throw new CorruptSection('not a btfvq database');
  if (view.getUint32(8, true) !== 1) throw new CorruptSection('format version is not 1');
  return {
    versions: view.getUint32(12, true),
    grid: { nb: view.getUint32(16, true), na: view.getUint32(20, true), nt: view.getUint32(24, true), np: view.getUint32(28, true) },
    sectionCount: view.getUint32(32, true),
    headLength: view.getUint32(36, true),
    fileSize: u64(view, 40),
  };
}

// The whole head [0, head_length): version records and the section table.
export function parseHead(bytes) {
  const head = parseHeader(bytes);
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let at = kHeaderBytes;
  head.records = [];
  for (let v = 0; v < head.versions; ++v, at += kVersionRecordBytes) {
    const rows = {};
    CODEBOOKS.forEach((name, k) => { rows[name] = view.getUint32(at + 4 * k, true); });
    head.records.push({ rows, materials: view.getUint32(at + 32, true) });
  }
  head.sections = [];
  const names = new TextDecoder();
  for (let s = 0; s < head.sectionCount; ++s) {
    const nameLength = view.getUint16(at + 42, true);
    head.sections.push({
      index: s,
      kind: view.getUint16(at, true) === 1 ? 'codebook' : 'material',
      encoding: view.getUint16(at + 2, true),
      version: view.getUint32(at + 4, true),
      offset: u64(view, at + 8),
      length: u64(view, at + 16),
      rawLength: u64(view, at + 24),
      checksum: hex64(view, at + 32),
      codebook: CODEBOOKS[view.getUint16(at + 40, true)],
      name: names.decode(bytes.subarray(at + 44, at + 44 + nameLength)),
    });
    at += 44 + nameLength;
  }
  if (at + 8 !== head.headLength) throw new CorruptSection('the section table does not end at head_length');
  if (crc64(bytes.subarray(0, at)) !== hex64(view, at)) throw new CorruptSection('the head checksum does not match');
  return head;
}

// The sections one material needs: the code-book chunks of its version and before (a row of
// version N references only rows of version N), then the material's own section.
export function sectionsOfMaterial(head, name) {
  const material = head.sections.find((s) => s.kind === 'material' && s.name === name);
  if (!material) throw new Error(`no material '${name}' in the database`);
  const chunks = head.sections.filter((s) => s.kind === 'codebook' && s.version <= material.version);
  return { chunks, material };
}

// Index field or value field, in the section's order: count and row length from the grid and the
// section header (docs/format.md "Section shape").
function fieldShapes(section, raw, grid) {
  const view = new DataView(raw.buffer, raw.byteOffset, raw.byteLength);
  if (section.kind === 'material') {
    const nameLength = view.getUint16(0, true);
    const w = view.getUint32(2 + nameLength, true), h = view.getUint32(6 + nameLength, true);
    return { headerBytes: 2 + nameLength + 17, fields: [{ kind: 'index', count: w * h, cols: w }, { kind: 'values', count: w * h, cols: w }] };
  }
  const rows = view.getUint32(12, true);
  const { nb, na, nt, np } = grid;
  const index = (cols) => ({ kind: 'index', count: rows * cols, cols });
  const values = (cols) => ({ kind: 'values', count: rows * cols, cols });
  const fields = {
    P1: [values(nb)], C: [values(2)], I1: [index(nb)], I2: [index(na)], P2: [index(na), values(na)],
    M: [index(1), index(1)], P3: [index(nt), values(nt)], P4: [index(np), values(np)],
  }[section.codebook];
  return { headerBytes: 16, fields };
}

function fieldHeaderBytes(kind) { return kind === 'index' ? 1 : 10; }

function fieldWidth(kind, bytes, at) {
  if (kind === 'index') return bytes[at];
  const mode = bytes[at], bits = bytes[at + 1];
  if (mode === 0 && bits === 32) return 32;
  if ((mode === 1 || mode === 2) && (bits === 8 || bits === 16)) return bits;
  throw new CorruptSection('unknown value coding');
}

function valueCoding(bytes, at) {
  const view = new DataView(bytes.buffer, bytes.byteOffset + at, 10);
  return { mode: bytes[at], bits: bytes[at + 1], min: view.getFloat32(2, true), max: view.getFloat32(6, true) };
}

// Values of w bits from an LSB-first packed stream (docs/format.md "Bit packing order").
function unpack(bytes, at, count, w) {
  const out = new Uint32Array(count);
  let pos = at * 8;
  for (let i = 0; i < count; ++i, pos += w) {
    let v = 0;
    for (let k = 0; k < w;) {
      const bit = pos + k, shift = bit % 8, take = Math.min(8 - shift, w - k);
      v += ((bytes[bit >>> 3] >>> shift) & ((1 << take) - 1)) * 2 ** k;
      k += take;
    }
    out[i] = v;
  }
  return out;
}

// A section being decoded from its stored bytes, which may still be arriving: each append() decodes
// as far as the bytes so far go (encoding 2 value by value; encodings 0 and 1 once complete).
// `fields[k].values` holds the codes, `header` the section header bytes.
export class SectionDecoder {
  constructor(section, grid) {
    this.section = section;
    this.grid = grid;
    this.stored = new Uint8Array(section.length);
    this.received = 0;
    this.fields = null;
  }
  // `chunk` continues the stored bytes.
  append(chunk) {
    this.stored.set(chunk, this.received);
    this.received += chunk.length;
    return this.advance();
  }
  complete() { return this.fields !== null && this.fields.every((f) => f.done === f.count); }
  // Throws unless the stored bytes, all here, have the table's checksum (values decoded before this
  // are drawn, but a damaged section ends in an error, never in a final frame).
  verify() {
    if (this.received !== this.section.length || crc64(this.stored) !== this.section.checksum)
      throw new CorruptSection(`section ${this.section.index} does not match its checksum`);
  }

  advance() {
    const { section, stored, received } = this;
    if (section.encoding === 2) return this.advanceModelled();
    if (received < section.length) return false;
    const raw = section.encoding === 1 ? zstdDecompress(stored) : stored;
    if (raw.length !== section.rawLength) throw new CorruptSection(`section ${section.index} decodes to ${raw.length} bytes, not ${section.rawLength}`);
    const shape = fieldShapes(section, raw, this.grid);
    this.header = raw.subarray(0, shape.headerBytes);
    let at = shape.headerBytes;
    this.fields = shape.fields.map((f) => {
      const width = fieldWidth(f.kind, raw, at);
      const field = { ...f, width, coding: f.kind === 'values' ? valueCoding(raw, at) : null };
      at += fieldHeaderBytes(f.kind);
      field.values = unpack(raw, at, f.count, width);
      field.done = f.count;
      at += Math.ceil((f.count * width) / 8);
      return field;
    });
    return true;
  }

  // Encoding 2: the header verbatim, then per field its header, the model, the stream length
  // (LEB128, not for the last) and the stream. Each field starts as soon as its header is here, so
  // the first values of a section decode while its later fields are still on their way.
  advanceModelled() {
    if (!this.fields && !this.readHeader()) return false;
    for (let k = 0; k < this.fields.length; ++k) {
      const f = this.fields[k];
      if (!f.decoder && !this.startField(k)) break;
      f.done = f.decoder.advance(this.received);
      if (!f.decoder.finished()) break;
    }
    return true;
  }

  readHeader() {
    const { stored, received, section } = this;
    const headerBytes = section.kind === 'material' ? 2 + stored[0] + 256 * stored[1] + 17 : 16;
    if (received < Math.min(section.length, Math.max(2, headerBytes))) return false;
    const shape = fieldShapes(section, stored, this.grid);
    this.header = stored.slice(0, shape.headerBytes);
    this.next = shape.headerBytes;  // where the next field's header starts
    this.fields = shape.fields.map((f) => ({ ...f, width: 0, coding: null, decoder: null, values: new Uint32Array(f.count), done: 0 }));
    return true;
  }

  // Field k's header, model and stream length, once they are here.
  startField(k) {
    const { stored, received, section } = this;
    const f = this.fields[k], last = k + 1 === this.fields.length;
    let at = this.next;
    if (received < Math.min(section.length, at + 16)) return false;
    f.width = fieldWidth(f.kind, stored, at);
    f.coding = f.kind === 'values' ? valueCoding(stored, at) : null;
    at += fieldHeaderBytes(f.kind);
    const model = stored[at++];
    let length = section.length - at;
    if (!last) {
      length = 0;
      for (let shift = 0; ; shift += 7) {
        if (shift > 28 || at >= section.length) throw new CorruptSection('invalid stream length');
        const b = stored[at++];
        length += (b & 0x7f) * 2 ** shift;
        if (!(b & 0x80)) break;
      }
    }
    if (at + length > section.length || (last && at + length !== section.length)) throw new CorruptSection('a field stream runs past the section');
    f.decoder = new FieldDecoder({ bytes: stored, streamAt: at, streamEnd: at + length, count: f.count, cols: f.cols, width: f.width, model });
    f.values = f.decoder.values;
    this.next = at + length;
    return true;
  }
}

// The value of one code of a value field (Quantizer::value of pipeline/format/packing.cpp).
export function dequantize(coding, codes) {
  const out = new Float32Array(codes.length);
  if (coding.mode === 0) {
    out.set(new Float32Array(codes.buffer, codes.byteOffset, codes.length));
    return out;
  }
  const L = 2 ** coding.bits - 1, { min, max } = coding;
  const clamp = (v) => Math.min(Math.max(v, min), max);
  if (coding.mode === 2) {
    const lmin = Math.log(min), lmax = Math.log(max);
    for (let i = 0; i < codes.length; ++i) {
      const q = codes[i];
      out[i] = q === 0 ? 0 : q === 1 ? min : q >= L ? max : clamp(Math.fround(Math.exp(lmin + (lmax - lmin) * ((q - 1) / (L - 1)))));
    }
    return out;
  }
  for (let i = 0; i < codes.length; ++i) {
    const q = codes[i];
    out[i] = q >= L ? max : clamp(Math.fround(min + (max - min) * (q / L)));
  }
  return out;
}

// A code-book chunk's rows: first_row and, per field, codes (index fields) or values.
export function chunkRows(decoded) {
  const view = new DataView(decoded.header.buffer, decoded.header.byteOffset, 16);
  return {
    codebook: decoded.section.codebook,
    firstRow: view.getUint32(8, true),
    rowCount: view.getUint32(12, true),
    fields: decoded.fields.map((f) => (f.kind === 'values' ? dequantize(f.coding, f.values) : f.values)),
  };
}

// A material section's header: name, size, dynamic range, raw bytes.
export function materialHeader(decoded) {
  const h = decoded.header;
  const view = new DataView(h.buffer, h.byteOffset, h.byteLength);
  const nameLength = view.getUint16(0, true);
  return {
    name: new TextDecoder().decode(h.subarray(2, 2 + nameLength)),
    width: view.getUint32(2 + nameLength, true),
    height: view.getUint32(6 + nameLength, true),
    hdr: h[10 + nameLength] === 1,
    rawBytes: u64(view, 11 + nameLength),
  };
}
