// The MLVQ decoder of pipeline/decode/decoder.cpp as a WebGL2 fragment shader: every pixel follows
// P6 -> P4 (linear over phi_v, wrapping) -> P3 (linear over theta_v) -> M -> P2/P1 (cubic Hermite
// along beta, linear in alpha) and I2/I1/C (linear in beta, then alpha), coding space -> RGB, with
// the P3, P4 and P6 scales, in 32-bit floats like kernels/decode.cl (whose well-conditioned onion
// angles it shares). The code-books live in textures, one value per texel, 4096 texels a row.

const kRow = 4096;  // texels per texture row: every WebGL2 implementation allows 4096

const vertexSource = `#version 300 es
void main() {
  // One triangle that covers the viewport.
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}`;

const fragmentSource = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
precision highp usampler2D;

uniform sampler2D P1, C, P2s, P3s, P4s, P6s;
uniform usampler2D I1, I2, P2i, M, P3i, P4i, P6i;
uniform int nb, na, nt, np;
uniform ivec2 size;        // material width, height
uniform int texelsReady;   // texels (row-major) whose P6 index has arrived
uniform int scalesReady;   // texels whose P6 scale has arrived (the others are drawn with scale 1)
uniform bool hdr;
uniform int scene;         // 0 plane (one light and view direction for every texel), 1 sphere
uniform vec2 light, view;  // (theta, phi) in degrees; on the sphere the light is in the camera frame
uniform float tiles;
uniform vec2 canvas;
out vec4 colour;

const float DEG = 0.017453292519943295;
const float kBackground = 40.0 / 255.0;

float f(sampler2D t, int i) { return texelFetch(t, ivec2(i & 4095, i >> 12), 0).r; }
int u(usampler2D t, int i) { return int(texelFetch(t, ivec2(i & 4095, i >> 12), 0).r); }

// Coding space -> RGB: BT.601 studio-swing inverse (LDR), LogLuv (HDR) (pipeline/colour.cpp).
vec3 to_rgb(float l, float a, float b) {
  if (!hdr)
    return max(vec3(1.1643828 * l + 1.5960273 * b - 222.921, 1.1643828 * l - 0.39176172 * a - 0.81296875 * b + 135.576,
                    1.1643828 * l + 2.0172344 * a - 276.836), 0.0);
  float Y = max(l, 0.0);
  if (Y <= 1e-12) return vec3(0.0);
  float uu = a / 255.0, v = max(b / 255.0, 1e-6);
  float X = Y * 9.0 * uu / (4.0 * v), Z = Y * (12.0 - 3.0 * uu - 20.0 * v) / (4.0 * v);
  return vec3(3.2404542 * X - 1.5371385 * Y - 0.4985314 * Z, -0.9692660 * X + 1.8760108 * Y + 0.0415560 * Z,
              0.0556434 * X - 0.2040259 * Y + 1.0572252 * Z);
}

// atan2 in degrees; 0 where both are 0 (undefined in GLSL, NaN on some GPUs), as in kernels/decode.cl.
float atan_deg(float y, float x) { return x == 0.0 && y == 0.0 ? 0.0 : atan(y, x) / DEG; }

float beta_node(int k) { return asin(-1.0 + 2.0 * float(k) / float(nb - 1)) / DEG; }

// Cubic Hermite of one P1 row in beta cell bi at t, with the original's tangents (decoder.cpp).
float hermite(int row, int bi, float t) {
  float p0 = f(P1, row + bi), p1 = f(P1, row + bi + 1);
  float m0 = bi == 0 ? p1 - p0 : (p1 - f(P1, row + bi - 1)) / 2.0;
  float m1 = bi == nb - 2 ? p1 - p0 : (f(P1, row + bi + 1) - p0) / 2.0;  // (sic)
  float h01 = -2.0 * t * t * t + 3.0 * t * t, h00 = 1.0 - h01, h11 = t * t * t - t * t, h10 = h11 - t * t + t;
  return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1;
}

// One P4 entry for one (light, view) pair, without the P6 scale (Decoder::evaluate_p4).
vec3 evaluate_p4(int p4_row, vec2 L, vec2 V) {
  if (!(L.x <= 90.0 && V.x <= 90.0)) return vec3(0.0);
  float phi_v = V.y - 360.0 * floor(V.y / 360.0);
  float az = L.y - V.y - 90.0;
  az -= 360.0 * floor(az / 360.0 + 0.5);
  float st = sin(L.x * DEG), ct = cos(L.x * DEG), sp = sin(az * DEG), cp = cos(az * DEG);
  float sb = clamp(cp * st, -1.0, 1.0), ly = sp * st;
  float beta = atan_deg(sb, sqrt(ct * ct + ly * ly));
  float alpha = atan_deg(ly, ct);
  int bi = clamp(int(floor((sb + 1.0) * 0.5 * float(nb - 1))), 0, nb - 2);
  float b0 = beta_node(bi), b1 = beta_node(bi + 1);
  float bw = clamp((beta - b0) / (b1 - b0), 0.0, 1.0);
  float a_cells = (alpha + 90.0) / (180.0 / float(na - 1));
  int ai = clamp(int(floor(a_cells)), 0, na - 2);
  float aw = clamp(a_cells - float(ai), 0.0, 1.0);
  // At or past the last theta_v node only that node counts: the cell's second node with weight 1.
  float t_cells = V.x / (90.0 / float(nt - 1));
  int ti = clamp(int(floor(t_cells)), 0, nt - 2);
  float tw = clamp(t_cells - float(ti), 0.0, 1.0);
  float p_cells = phi_v / (360.0 / float(np));
  int pi0 = clamp(int(floor(p_cells)), 0, np - 1);
  float pw = clamp(p_cells - float(pi0), 0.0, 1.0);
  int pi1 = pi0 + 1 == np ? 0 : pi0 + 1;

  vec3 rgb = vec3(0.0);
  for (int p = 0; p < 2; ++p) {
    float wp = p == 0 ? 1.0 - pw : pw;
    if (wp == 0.0) continue;
    int p4e = p4_row * np + (p == 0 ? pi0 : pi1);
    float s4 = wp * f(P4s, p4e);
    int p3_row = u(P4i, p4e) * nt;
    for (int t = 0; t < 2; ++t) {
      float wt = t == 0 ? 1.0 - tw : tw;
      if (wt == 0.0) continue;
      int p3e = p3_row + ti + t;
      float s = s4 * wt * f(P3s, p3e);
      int me = u(P3i, p3e);
      int p2_row = u(M, 2 * me) * na, i2_row = u(M, 2 * me + 1) * na;
      float yy = 0.0, cb = 0.0, cr = 0.0;
      for (int a = 0; a < 2; ++a) {
        float w = a == 0 ? 1.0 - aw : aw;
        int an = ai + a;
        yy += w * f(P2s, p2_row + an) * hermite(u(P2i, p2_row + an) * nb, bi, bw);
        int i1_row = u(I2, i2_row + an) * nb;
        int c0 = 2 * u(I1, i1_row + bi), c1 = 2 * u(I1, i1_row + bi + 1);
        cb += w * ((1.0 - bw) * f(C, c0) + bw * f(C, c1));
        cr += w * ((1.0 - bw) * f(C, c0 + 1) + bw * f(C, c1 + 1));
      }
      rgb += s * to_rgb(yy, cb, cr);
    }
  }
  return rgb;
}

// The decoded texel (x, y) (wrapped), or the background while its P6 entry is still on its way.
vec4 texel(int x, int y, vec2 L, vec2 V) {
  x = ((x % size.x) + size.x) % size.x;
  y = ((y % size.y) + size.y) % size.y;
  int t = y * size.x + x;
  if (t >= texelsReady) return vec4(vec3(kBackground), 1.0);
  int entry = u(P6i, t);
  if (entry == 0) return vec4(0.0, 0.0, 0.0, 1.0);  // a texel that was not compressed
  float s6 = t < scalesReady ? f(P6s, t) : 1.0;
  vec3 v = evaluate_p4(entry - 1, L, V) * s6;
  return vec4(hdr ? pow(max(v, 0.0), vec3(1.0 / 2.2)) : v / 255.0, 1.0);
}

vec3 unit(vec2 d) { return vec3(sin(d.x * DEG) * cos(d.y * DEG), sin(d.x * DEG) * sin(d.y * DEG), cos(d.x * DEG)); }
// theta by atan2, not acos: acos near 1 loses the small angles (SwiftShader's drew a dark spot on
// the sphere where the light meets the normal).
vec2 direction_of(vec3 v) {
  float phi = atan_deg(v.y, v.x);
  return vec2(atan_deg(length(v.xy), v.z), phi < 0.0 ? phi + 360.0 : phi);
}

void main() {
  vec2 q = gl_FragCoord.xy / canvas;  // (0, 0) bottom left
  if (scene == 0) {
    // The flat sample seen along the view direction, row 0 of the material at the top.
    colour = texel(int(floor(q.x * tiles * float(size.x))), int(floor((1.0 - q.y) * tiles * float(size.y))), light, view);
    return;
  }
  // The sphere of pipeline/decode/preview.cpp: orthographic camera on +z, longitude/latitude texture.
  vec2 xy = q * 2.0 - 1.0;
  float r2 = dot(xy, xy);
  if (r2 >= 1.0) {
    colour = vec4(vec3(kBackground), 1.0);
    return;
  }
  vec3 n = vec3(xy, sqrt(1.0 - r2));
  float h = length(n.xz);
  vec3 tangent = h > 1e-6 ? vec3(n.z / h, 0.0, -n.x / h) : vec3(1.0, 0.0, 0.0);
  vec3 bitangent = cross(n, tangent);
  vec3 l = unit(light);
  if (dot(l, n) <= 0.0) {
    colour = vec4(0.0, 0.0, 0.0, 1.0);
    return;
  }
  mat3 to_local = transpose(mat3(tangent, bitangent, n));
  float tu = (atan(n.x, n.z) / (2.0 * 3.141592653589793) + 0.5) * tiles;
  float tv = acos(clamp(n.y, -1.0, 1.0)) / 3.141592653589793 * tiles;
  colour = texel(int(floor(fract(tu) * float(size.x))), int(floor(fract(tv) * float(size.y))),
                 direction_of(to_local * l), direction_of(to_local * vec3(0.0, 0.0, 1.0)));
}`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(shader)}`);
  return shader;
}

const kFloatTextures = ['P1', 'C', 'P2s', 'P3s', 'P4s', 'P6s'];
const kIndexTextures = ['I1', 'I2', 'P2i', 'M', 'P3i', 'P4i', 'P6i'];

export class MaterialRenderer {
  constructor(canvas) {
    const gl = canvas.getContext('webgl2', { preserveDrawingBuffer: true, antialias: false });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl;
    this.canvas = canvas;
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, vertexSource));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, fragmentSource));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(`shader: ${gl.getProgramInfoLog(program)}`);
    this.program = program;
    gl.useProgram(program);
    this.units = {};
    [...kFloatTextures, ...kIndexTextures].forEach((name, unit) => {
      this.units[name] = unit;
      gl.uniform1i(gl.getUniformLocation(program, name), unit);
    });
    this.vao = gl.createVertexArray();
  }

  // One flat array as a texture of kRow-wide rows (padded; never empty).
  upload(name, data) {
    const gl = this.gl;
    const float = data instanceof Float32Array;
    const height = Math.max(1, Math.ceil(data.length / kRow));
    const padded = new (float ? Float32Array : Uint32Array)(kRow * height);
    padded.set(data);
    gl.activeTexture(gl.TEXTURE0 + this.units[name]);
    if (!this[`tex_${name}`]) this[`tex_${name}`] = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this[`tex_${name}`]);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, float ? gl.R32F : gl.R32UI, kRow, height, 0, float ? gl.RED : gl.RED_INTEGER,
                  float ? gl.FLOAT : gl.UNSIGNED_INT, padded);
  }

  // books: P1, C (Float32Array), I1, I2, M (Uint32Array), P2/P3/P4 {index, scale}; grid {nb, na, nt, np}.
  setCodebooks(books, grid) {
    this.upload('P1', books.P1);
    this.upload('C', books.C);
    this.upload('I1', books.I1);
    this.upload('I2', books.I2);
    this.upload('M', books.M);
    for (const k of ['P2', 'P3', 'P4']) {
      this.upload(`${k}i`, books[k].index);
      this.upload(`${k}s`, books[k].scale);
    }
    this.grid = grid;
  }

  // The P6 map as far as it has arrived: entries (P4 row + 1) and scales, texel-major.
  setP6(material, entries, scales, texelsReady, scalesReady) {
    this.upload('P6i', entries);
    this.upload('P6s', scales);
    this.material = material;
    this.texelsReady = texelsReady;
    this.scalesReady = scalesReady;
  }

  // view: {scene: 'plane'|'sphere', light: [theta, phi], view: [theta, phi], tiles}
  draw(v) {
    const gl = this.gl, p = this.program, g = this.grid, m = this.material;
    const loc = (name) => gl.getUniformLocation(p, name);
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.uniform1i(loc('nb'), g.nb);
    gl.uniform1i(loc('na'), g.na);
    gl.uniform1i(loc('nt'), g.nt);
    gl.uniform1i(loc('np'), g.np);
    gl.uniform2i(loc('size'), m.width, m.height);
    gl.uniform1i(loc('texelsReady'), this.texelsReady);
    gl.uniform1i(loc('scalesReady'), this.scalesReady);
    gl.uniform1i(loc('hdr'), m.hdr ? 1 : 0);
    gl.uniform1i(loc('scene'), v.scene === 'sphere' ? 1 : 0);
    gl.uniform2f(loc('light'), v.light[0], v.light[1]);
    gl.uniform2f(loc('view'), v.view[0], v.view[1]);
    gl.uniform1f(loc('tiles'), v.tiles);
    gl.uniform2f(loc('canvas'), this.canvas.width, this.canvas.height);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
}
