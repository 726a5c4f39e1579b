// Section encoding 2 of docs/format.md in the browser: the adaptive binary range decoder, its bit,
// integer and bit-tree models, and the per-field symbol models (pipeline/format/range_coder.cpp and
// section_coding.cpp). Integer arithmetic only, so the values are exactly the C++ decoder's.
//
// A field decodes *resumably*: the page hands it the bytes received so far and it decodes every
// value whose bits are certainly there, so a picture can be drawn before the section has arrived.

const kProbBits = 15;
const kOne = 1 << kProbBits;
const kFastBits = 3;
const kSlowBits = 7;
const kTop = 1 << 24;
// A value costs at most 39 coded bits (2 flags + a 6-bit length + 31 bits) and a bit at most 2
// renormalization bytes (p >= 16 / 2^15): with this many bytes ahead, one value never runs short.
export const kMaxBytesPerValue = 128;

// `n` bit models (docs/format.md "Bit model") in three arrays, so a field's thousands of models cost
// no objects.
export class BitModels {
  constructor(n) {
    this.fast = new Uint16Array(n).fill(1 << 14);
    this.slow = new Uint16Array(n).fill(1 << 14);
    this.seen = new Uint8Array(n);
  }
}

export class CorruptSection extends Error {}

export class RangeDecoder {
  // bytes[start, end) is the stream.
  constructor(bytes, start, end) {
    this.bytes = bytes;
    this.pos = start;
    this.end = end;
    this.range = 0xffffffff;
    this.code = 0;
    if (this.next() !== 0) throw new CorruptSection('range coder stream does not start with a zero byte');
    for (let i = 0; i < 4; ++i) this.code = this.code * 256 + this.next();
    if (this.code === this.range) throw new CorruptSection('range coder stream starts with an impossible code');
  }
  next() {
    if (this.pos >= this.end) throw new CorruptSection('range coder stream is truncated');
    return this.bytes[this.pos++];
  }
  bit(m, i) {
    const p = (m.fast[i] + m.slow[i]) >>> 1;
    const bound = (this.range >>> kProbBits) * p;
    let b;
    if (this.code < bound) {
      this.range = bound;
      b = 0;
    } else {
      this.code -= bound;
      this.range -= bound;
      b = 1;
    }
    update(m, i, b);
    while (this.range < kTop) {
      this.range = this.range * 256;
      this.code = this.code * 256 + this.next();
    }
    if (this.code >= this.range) throw new CorruptSection('range coder stream is inconsistent');
    return b;
  }
  finish() {
    if (this.pos !== this.end) throw new CorruptSection(`range coder stream has ${this.end - this.pos} bytes past its end`);
  }
}

function update(m, i, b) {
  const seen = m.seen[i];
  const shift = Math.min(kSlowBits, 32 - Math.clz32(seen + 1));
  if (seen < 255) m.seen[i] = seen + 1;
  let fast = m.fast[i], slow = m.slow[i];
  if (b === 0) {
    fast += (kOne - fast) >> kFastBits;
    slow += (kOne - slow) >> shift;
  } else {
    fast -= fast >> kFastBits;
    slow -= slow >> shift;
  }
  m.fast[i] = fast;
  m.slow[i] = Math.min(Math.max(slow, 32), kOne - 32);
}

// IntegerModel: bit length as a 6-level tree, then the bits below the leading one (the top 3 with
// models by (length, prefix), the rest by (length, position)).
const kContextBits = 3;
class IntegerModel {
  constructor() {
    this.length = new BitModels(64);
    this.high = new BitModels(33 << kContextBits);
    this.low = new BitModels(33 * 32);
  }
  decode(d) {
    let m = 1;
    for (let i = 5; i >= 0; --i) m = 2 * m + d.bit(this.length, m);
    const n = m - 64;
    if (n > 32) throw new CorruptSection('an integer of more than 32 bits');
    if (n === 0) return 0;
    let v = 1, ctx = 1;
    for (let i = n - 2; i >= 0; --i) {
      let b;
      if (n - 2 - i < kContextBits) {
        b = d.bit(this.high, (n << kContextBits) + ctx);
        ctx = 2 * ctx + b;
      } else {
        b = d.bit(this.low, n * 32 + i);
      }
      v = v * 2 + b;
    }
    return v;
  }
}

// A full bit tree of `bits` bits (one model per prefix).
class SymbolModel {
  constructor(bits) {
    this.bits = bits;
    this.tree = new BitModels(1 << bits);
  }
  decode(d) {
    let m = 1;
    for (let i = 0; i < this.bits; ++i) m = 2 * m + d.bit(this.tree, m);
    return m - (1 << this.bits);
  }
}

const Tree = 0, Delta = 1, Plain = 2;
const Above = 1, Median = 2, Slope = 3;

export function validModel(model, w, cols) {
  const literal = (model >> 1) & 3, prediction = (model >> 3) & 3;
  const perColumn = (model >> 5) & 1, byActivity = (model >> 6) & 1;
  if (model >= 128 || literal > Plain) return false;
  if (literal !== Delta && (prediction !== 0 || byActivity)) return false;
  if (perColumn && (cols < 2 || cols > 16 || (literal === Tree && w > 12))) return false;
  return true;
}

const maskOf = (w) => (w >= 32 ? 0xffffffff : (2 ** w) - 1);
function zigzagBack(z, w) {
  const m = maskOf(w);
  return z % 2 === 1 ? (m - Math.floor(z / 2)) % (m + 1) : Math.floor(z / 2);
}

// One field's values, decoded in order into `values` (a Uint32Array of `count`), as far as the
// bytes allow. Models are made when first needed (they all start in the same state).
export class FieldDecoder {
  constructor({ bytes, streamAt, streamEnd, count, cols, width, model }) {
    if (!validModel(model, width, cols)) throw new CorruptSection(`unknown symbol model ${model}`);
    Object.assign(this, { bytes, streamAt, streamEnd, count, cols, w: width, model });
    this.values = new Uint32Array(count);
    this.done = 0;  // values decoded so far
    this.state = 2;  // how the previous value was coded: 0 left, 1 above, 2 literal
    const contexts = (model >> 5) & 1 ? cols : 1;
    this.contexts = contexts;
    this.sameLeft = new BitModels(6 * contexts);
    this.sameAbove = new BitModels(3 * contexts);
    this.trees = new Map();
    this.integers = new Map();
    this.rc = null;
  }
  tree(key, bits) {
    if (!this.trees.has(key)) this.trees.set(key, new SymbolModel(bits));
    return this.trees.get(key);
  }
  integer(key) {
    if (!this.integers.has(key)) this.integers.set(key, new IntegerModel());
    return this.integers.get(key);
  }
  finished() { return this.done === this.count; }

  // Decodes what bytes[0, available) allow; returns the number of values decoded so far.
  advance(available) {
    const whole = available >= this.streamEnd;
    if (!this.rc) {
      if (!whole && available < this.streamAt + 5 + kMaxBytesPerValue) return this.done;
      this.rc = new RangeDecoder(this.bytes, this.streamAt, this.streamEnd);
    }
    while (this.done < this.count && (whole || this.rc.pos + kMaxBytesPerValue <= available)) this.decodeOne(this.done++);
    if (this.done === this.count && whole) this.rc.finish();
    return this.done;
  }

  decodeOne(i) {
    const { rc, cols, w, model, values } = this;
    const flags = model & 1, byActivity = (model >> 6) & 1;
    const literal = (model >> 1) & 3, prediction = (model >> 3) & 3;
    const col = i % cols;
    const hasLeft = col !== 0, hasAbove = i >= cols;
    const left = hasLeft ? values[i - 1] : 0, above = hasAbove ? values[i - cols] : 0;
    const ctx = this.contexts > 1 ? col : 0;
    if (flags && hasLeft) {
      if (rc.bit(this.sameLeft, ctx * 6 + this.state * 2 + (hasAbove && above === left ? 1 : 0))) {
        values[i] = left;
        this.state = 0;
        return;
      }
    }
    if (flags && hasAbove && !(hasLeft && above === left)) {
      if (rc.bit(this.sameAbove, ctx * 3 + this.state)) {
        values[i] = above;
        this.state = 1;
        return;
      }
    }
    this.state = 2;
    let v = 0;
    if (literal === Tree) {
      if (w > 16) {
        v = this.tree('top', w - 16).decode(rc) * 65536;
        v += this.tree('mid', 8).decode(rc) * 256;
        v += this.tree('low', 8).decode(rc);
      } else {
        v = this.tree(ctx, w).decode(rc);
      }
    } else if (literal === Delta) {
      const mask = maskOf(w);
      const hasSecond = col >= 2;
      const second = hasSecond ? values[i - 2] : 0;
      let predicted = 0;
      if (hasSecond && prediction === Slope) {
        predicted = Math.min(Math.max(2 * left - second, 0), mask);
      } else if (hasLeft && hasAbove && prediction === Median) {
        const corner = values[i - cols - 1];
        const lo = Math.min(left, above), hi = Math.max(left, above);
        predicted = corner >= hi ? lo : corner <= lo ? hi : (left + above - corner) % (mask + 1);
      } else if (hasLeft && (prediction !== Above || !hasAbove)) {
        predicted = left;
      } else if (hasAbove) {
        predicted = above;
      }
      const predicts = hasLeft || hasAbove ? 1 : 0;
      const activity = hasSecond ? Math.abs(left - second) : hasLeft && hasAbove ? Math.abs(left - above) : 0;
      const cls = !byActivity || activity === 0 ? 0 : activity < 4 ? 1 : activity < 32 ? 2 : 3;
      const z = this.integer((ctx * 4 + cls) * 2 + predicts).decode(rc);
      v = (predicted + zigzagBack(z, w)) % (mask + 1);
    } else {
      v = this.integer(ctx * 8).decode(rc);
      if (v > maskOf(w)) throw new CorruptSection('a value wider than its field');
    }
    values[i] = v;
  }
}
