// Progressive streaming of one material (paper: the database is sent section by section): the head,
// then the code-book chunks the material uses, then its P6 map in pieces, every byte by HTTP Range
// from /v1/databases/{db}/content of one pinned version. Each step is written to an event log
// (window.viewerEvents) so that the order of fetches and frames can be checked.
import { kHeaderBytes, parseHeader, parseHead, sectionsOfMaterial, SectionDecoder, chunkRows, dequantize, materialHeader } from './database.js';

export const events = [];
export function logEvent(type, details = {}) {
  events.push({ type, t: Math.round(performance.now() * 10) / 10, ...details });
}

// The P6 map is fetched in this many pieces at least (each at least kMinPiece bytes), so that the
// first rows are drawn while the rest is on its way.
const kP6Pieces = 8;
const kMinPiece = 256;

class Content {
  constructor(db) {
    this.base = `/v1/databases/${encodeURIComponent(db)}/content`;
    this.version = null;  // pinned by the first answer: later pieces come from the same file
    this.received = 0;
  }
  // Bytes [from, to), handed to onChunk as they arrive.
  async range(from, to, what, onChunk) {
    const url = this.version === null ? this.base : `${this.base}?version=${this.version}`;
    logEvent('fetch', { what, from, to });
    const response = await fetch(url, { headers: { Range: `bytes=${from}-${to - 1}` }, cache: 'no-store' });
    if (response.status !== 206) throw new Error(`${url}: HTTP ${response.status} for bytes ${from}-${to - 1}`);
    if (this.version === null) this.version = response.headers.get('X-Database-Version');
    const reader = response.body.getReader();
    let got = 0;
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      got += value.length;
      this.received += value.length;
      onChunk(value);
    }
    if (got !== to - from) throw new Error(`${url}: ${got} bytes for a range of ${to - from}`);
    logEvent('received', { what, from, to });
  }
  async bytes(from, to, what) {
    const out = new Uint8Array(to - from);
    let at = 0;
    await this.range(from, to, what, (chunk) => { out.set(chunk, at); at += chunk.length; });
    return out;
  }
}

// All rows of each code-book, chunks placed at their first row.
function assembleCodebooks(chunks) {
  const rows = {};
  for (const c of chunks) rows[c.codebook] = Math.max(rows[c.codebook] || 0, c.firstRow + c.rowCount);
  const books = {};
  const width = (c) => c.fields[0].length / Math.max(1, c.rowCount);
  const place = (name, field, Type) => {
    const parts = chunks.filter((c) => c.codebook === name);
    const cols = parts.length ? width(parts[0]) : 1;
    const out = new Type((rows[name] || 0) * cols);
    for (const c of parts) out.set(c.fields[field], c.firstRow * cols);
    return out;
  };
  books.P1 = place('P1', 0, Float32Array);
  books.C = place('C', 0, Float32Array);
  books.I1 = place('I1', 0, Uint32Array);
  books.I2 = place('I2', 0, Uint32Array);
  for (const k of ['P2', 'P3', 'P4']) books[k] = { index: place(k, 0, Uint32Array), scale: place(k, 1, Float32Array) };
  // M: (P2 row, I2 row) per entry, interleaved as the decoder reads it.
  const p2 = place('M', 0, Uint32Array), i2 = place('M', 1, Uint32Array);
  books.M = new Uint32Array(2 * p2.length);
  p2.forEach((v, i) => { books.M[2 * i] = v; books.M[2 * i + 1] = i2[i]; });
  return books;
}

// Streams `material` of `db`; calls onProgress({received, total, sections, sectionCount}) and
// onFrame(p6) whenever more of the P6 map can be drawn (p6.final on the last call); returns the
// head and `total`, the bytes the material needs (head and sections).
export async function streamMaterial(db, material, { onProgress, onCodebooks, onFrame }) {
  const content = new Content(db);
  const first = await content.bytes(0, kHeaderBytes, 'header');
  const { headLength } = parseHeader(first);
  const headBytes = new Uint8Array(headLength);
  headBytes.set(first);
  headBytes.set(await content.bytes(kHeaderBytes, headLength, 'head'), kHeaderBytes);
  const head = parseHead(headBytes);
  const { chunks, material: section } = sectionsOfMaterial(head, material);
  const needed = [...chunks, section];
  const total = headLength + needed.reduce((n, s) => n + s.length, 0);
  let sectionsDone = 0;
  const progress = () => onProgress({ received: content.received, total, sections: sectionsDone, sectionCount: needed.length, fileSize: head.fileSize });
  progress();
  logEvent('head', { sections: head.sections.length, needed: needed.length, neededBytes: total - headLength, fileSize: head.fileSize });

  const rows = [];
  for (const s of chunks) {
    const decoder = new SectionDecoder(s, head.grid);
    await content.range(s.offset, s.offset + s.length, `codebook ${s.codebook} v${s.version}`, (c) => { decoder.append(c); progress(); });
    if (!decoder.complete()) throw new Error(`code-book section ${s.index} did not decode`);
    decoder.verify();
    rows.push(chunkRows(decoder));
    ++sectionsDone;
    progress();
  }
  onCodebooks(assembleCodebooks(rows), head.grid);

  // The P6 map: each piece decodes as many texels as its bytes allow, and they are drawn at once.
  const p6 = new SectionDecoder(section, head.grid);
  const piece = Math.max(kMinPiece, Math.ceil(section.length / kP6Pieces));
  let drawn = -1;
  for (let from = section.offset; from < section.offset + section.length; from += piece) {
    const to = Math.min(from + piece, section.offset + section.length);
    await content.range(from, to, 'p6', (c) => { p6.append(c); progress(); });
    if (!p6.fields || !p6.header) continue;
    const [index, scale] = p6.fields;
    const ready = index.done + scale.done;
    if (ready === drawn) continue;
    drawn = ready;
    const final = p6.complete();
    if (final) {
      p6.verify();
      ++sectionsDone;
    }
    progress();
    onFrame({
      header: materialHeader(p6), entries: index.values, scales: scale.coding ? dequantize(scale.coding, scale.values) : new Float32Array(scale.count),
      texelsReady: index.done, scalesReady: scale.done, final,
    });
  }
  if (!p6.complete()) throw new Error('the P6 map did not decode');
  logEvent('done', { received: content.received, total });
  return { head, content, total };
}
