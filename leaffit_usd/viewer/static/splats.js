// leaffit-usd edit — the capture drawn as Gaussian splats (WebGL2), and the overlays drawn over it.
//
// Each Gaussian is a screen-space ellipse (EWA splatting): its 3D covariance
// Sigma = R S S^T R^T (R from its quaternion, S its scales) is projected to the screen as
// Sigma' = J W Sigma W^T J^T (W: the view rotation; J: the Jacobian of the perspective projection
// at the Gaussian's centre, in pixels), plus 0.3 px^2 on the diagonal (a pixel's footprint, as
// splat viewers do). The ellipse is a quad along Sigma''s eigenvectors, 3 standard deviations
// out; each fragment gets alpha = opacity * exp(-d^2 / 2), d the Mahalanobis distance. The quads
// are drawn back to front (sort-worker.js) and blended "over" with premultiplied colours.
//
// Per Gaussian the GPU holds two RGBA32UI texels (centre as float bits + RGBA8 colour;
// float16 scales + int16 quaternion) and one RGBA8 tint texel (the label colour and how much of
// it to mix in; the selection). The sorted order is a per-instance attribute.

const TEX_W = 4096;

const SPLAT_VS = `#version 300 es
precision highp float;
precision highp int;
precision highp usampler2D;
uniform usampler2D u_data;
uniform sampler2D u_tint;
uniform mat4 u_view, u_proj;
uniform vec2 u_viewport, u_focal;
in vec2 a_corner;
in uint a_index;
out vec4 v_color;
out vec2 v_uv;
void main() {
  int i2 = int(a_index) * 2;
  ivec2 t0 = ivec2(i2 % ${TEX_W}, i2 / ${TEX_W});
  uvec4 d0 = texelFetch(u_data, t0, 0);
  uvec4 d1 = texelFetch(u_data, t0 + ivec2(1, 0), 0);
  vec4 cam = u_view * vec4(uintBitsToFloat(d0.xyz), 1.0);
  vec4 clip = u_proj * cam;
  float lim = 1.2 * clip.w;
  if (cam.z > -1e-4 || abs(clip.x) > lim || abs(clip.y) > lim) { gl_Position = vec4(0.0, 0.0, 2.0, 1.0); return; }
  vec2 sxy = unpackHalf2x16(d1.x);
  float sz = unpackHalf2x16(d1.y).x;
  // int16 w, x (d1.z) and y, z (d1.w), low half first
  vec4 q = vec4(float(int(d1.z << 16) >> 16), float(int(d1.z) >> 16),
                float(int(d1.w << 16) >> 16), float(int(d1.w) >> 16));
  q = normalize(q);
  float w = q.x, x = q.y, y = q.z, z = q.w;
  mat3 R = mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
                2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
                2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
  mat3 M = R * mat3(sxy.x, 0.0, 0.0, 0.0, sxy.y, 0.0, 0.0, 0.0, sz);
  mat3 sigma = M * transpose(M);
  float depth = -cam.z;
  mat3 J = mat3(u_focal.x / depth, 0.0, 0.0,
                0.0, u_focal.y / depth, 0.0,
                u_focal.x * cam.x / (depth * depth), u_focal.y * cam.y / (depth * depth), 0.0);
  mat3 T = J * mat3(u_view);
  mat3 c2 = T * sigma * transpose(T);
  float a = c2[0][0] + 0.3, b = c2[0][1], c = c2[1][1] + 0.3;
  float mid = 0.5 * (a + c), rad = length(vec2(0.5 * (a - c), b));
  float l1 = mid + rad, l2 = max(mid - rad, 0.05);
  vec2 e1 = abs(b) < 1e-12 ? (a >= c ? vec2(1.0, 0.0) : vec2(0.0, 1.0)) : normalize(vec2(b, l1 - a));
  vec2 e2 = vec2(-e1.y, e1.x);
  float s1 = sqrt(l1), s2 = sqrt(l2);
  float r1 = min(3.0 * s1, 1024.0), r2 = min(3.0 * s2, 1024.0);
  vec2 off = a_corner.x * r1 * e1 + a_corner.y * r2 * e2;
  gl_Position = vec4(clip.xy / clip.w + off * 2.0 / u_viewport, 0.0, 1.0);
  v_uv = vec2(a_corner.x * r1 / s1, a_corner.y * r2 / s2);
  vec4 rgba = vec4(uvec4(d0.w & 255u, (d0.w >> 8) & 255u, (d0.w >> 16) & 255u, d0.w >> 24)) / 255.0;
  vec4 tint = texelFetch(u_tint, ivec2(int(a_index) % ${TEX_W}, int(a_index) / ${TEX_W}), 0);
  v_color = vec4(mix(rgba.rgb, tint.rgb, tint.a), rgba.a);
}`;

const SPLAT_FS = `#version 300 es
precision highp float;
in vec4 v_color;
in vec2 v_uv;
out vec4 fragColor;
void main() {
  float alpha = v_color.a * exp(-0.5 * dot(v_uv, v_uv));
  if (alpha < 1.0 / 255.0) discard;
  fragColor = vec4(v_color.rgb * alpha, alpha);
}`;

const LINE_VS = `#version 300 es
uniform mat4 u_mvp;
uniform float u_size;
in vec3 a_pos;
void main() { gl_Position = u_mvp * vec4(a_pos, 1.0); gl_PointSize = u_size; }`;

const LINE_FS = `#version 300 es
precision highp float;
uniform vec4 u_color;
out vec4 fragColor;
void main() { fragColor = vec4(u_color.rgb * u_color.a, u_color.a); }`;

function program(gl, vs, fs) {
  const make = (type, src) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
    return s;
  };
  const p = gl.createProgram();
  gl.attachShader(p, make(gl.VERTEX_SHADER, vs));
  gl.attachShader(p, make(gl.FRAGMENT_SHADER, fs));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error('program: ' + gl.getProgramInfoLog(p));
  return p;
}

function uniforms(gl, p, names) {
  const u = {};
  for (const n of names) u[n] = gl.getUniformLocation(p, n);
  return u;
}

// Unpack the server's splats payload (see ViewerSession.splats_bytes) for n Gaussians.
export function parseSplats(buf, n) {
  return {
    positions: new Float32Array(buf, 0, 3 * n),
    scales: new Uint16Array(buf, 12 * n, 3 * n),        // float16 bits
    rotations: new Uint16Array(buf, 18 * n, 4 * n),     // int16 bits (w, x, y, z)
    rgba: new Uint8Array(buf, 26 * n, 4 * n),
  };
}

export class SplatRenderer {
  constructor(gl) {
    this.gl = gl;
    this.n = 0;
    this.prog = program(gl, SPLAT_VS, SPLAT_FS);
    this.u = uniforms(gl, this.prog, ['u_data', 'u_tint', 'u_view', 'u_proj', 'u_viewport', 'u_focal']);
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    const quad = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, quad);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    const lc = gl.getAttribLocation(this.prog, 'a_corner');
    gl.enableVertexAttribArray(lc);
    gl.vertexAttribPointer(lc, 2, gl.FLOAT, false, 0, 0);
    this.orderBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.orderBuf);
    const li = gl.getAttribLocation(this.prog, 'a_index');
    gl.enableVertexAttribArray(li);
    gl.vertexAttribIPointer(li, 1, gl.UNSIGNED_INT, 0, 0);
    gl.vertexAttribDivisor(li, 1);
    gl.bindVertexArray(null);
    this.dataTex = gl.createTexture();
    this.tintTex = gl.createTexture();
    this.hasOrder = false;
  }

  setData(s, n) {
    // two RGBA32UI texels per Gaussian: [x, y, z (float bits), rgba] [sx|sy, sz, qw|qx, qy|qz]
    const gl = this.gl;
    this.n = n;
    const rows = Math.max(1, Math.ceil((2 * n) / TEX_W));
    const d = new Uint32Array(rows * TEX_W * 4);
    const fbits = new Uint32Array(s.positions.buffer, s.positions.byteOffset, 3 * n);
    const rgba = new Uint32Array(n);
    new Uint8Array(rgba.buffer).set(s.rgba);
    const rot = new Uint32Array(2 * n);
    new Uint16Array(rot.buffer).set(s.rotations);
    const sc = s.scales;
    for (let i = 0; i < n; i++) {
      const o = 8 * i, p = 3 * i;
      d[o] = fbits[p]; d[o + 1] = fbits[p + 1]; d[o + 2] = fbits[p + 2]; d[o + 3] = rgba[i];
      d[o + 4] = sc[p] | (sc[p + 1] << 16); d[o + 5] = sc[p + 2];
      d[o + 6] = rot[2 * i]; d[o + 7] = rot[2 * i + 1];
    }
    this._texture(this.dataTex, gl.RGBA32UI, TEX_W, rows, gl.RGBA_INTEGER, gl.UNSIGNED_INT, d);
    this.tintRows = Math.max(1, Math.ceil(n / TEX_W));
    this._texture(this.tintTex, gl.RGBA8, TEX_W, this.tintRows, gl.RGBA, gl.UNSIGNED_BYTE,
      new Uint8Array(this.tintRows * TEX_W * 4));
  }

  _texture(tex, internal, w, h, format, type, data) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, type, data);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  }

  setTint(tint) {
    // tint: Uint8Array (n * 4): RGB of the label colour, A how much of it replaces the colour
    const gl = this.gl;
    const full = new Uint8Array(this.tintRows * TEX_W * 4);
    full.set(tint);
    gl.bindTexture(gl.TEXTURE_2D, this.tintTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, TEX_W, this.tintRows, gl.RGBA, gl.UNSIGNED_BYTE, full);
  }

  setOrder(order) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.orderBuf);
    gl.bufferData(gl.ARRAY_BUFFER, order, gl.DYNAMIC_DRAW);
    this.hasOrder = true;
  }

  draw(camera, width, height) {
    // width, height: drawing buffer pixels
    if (!this.n || !this.hasOrder) return;
    const gl = this.gl;
    gl.viewport(0, 0, width, height);
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.depthMask(false);
    gl.enable(gl.BLEND);
    gl.blendFuncSeparate(gl.ONE, gl.ONE_MINUS_SRC_ALPHA, gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(this.prog);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.dataTex);
    gl.uniform1i(this.u.u_data, 0);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, this.tintTex);
    gl.uniform1i(this.u.u_tint, 1);
    gl.uniformMatrix4fv(this.u.u_view, false, camera.matrixWorldInverse.elements);
    gl.uniformMatrix4fv(this.u.u_proj, false, camera.projectionMatrix.elements);
    gl.uniform2f(this.u.u_viewport, width, height);
    const fy = (height / 2) / Math.tan((camera.fov * Math.PI) / 360);
    gl.uniform2f(this.u.u_focal, fy, fy);
    gl.bindVertexArray(this.vao);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, this.n);
    gl.bindVertexArray(null);
  }
}

// Lines, triangles and points over the splats (the fitted leaf, the split clicks): no depth test.
export class OverlayRenderer {
  constructor(gl) {
    this.gl = gl;
    this.prog = program(gl, LINE_VS, LINE_FS);
    this.u = uniforms(gl, this.prog, ['u_mvp', 'u_color', 'u_size']);
    this.loc = gl.getAttribLocation(this.prog, 'a_pos');
    this.items = new Map();  // name -> {vao, count, mode, color, size, elements}
  }

  set(name, positions, indices, mode, color, size = 1) {
    // positions: Float32Array (V*3), display frame; indices: Uint32Array or null
    const gl = this.gl;
    this.remove(name);
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const vb = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, vb);
    gl.bufferData(gl.ARRAY_BUFFER, positions, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(this.loc);
    gl.vertexAttribPointer(this.loc, 3, gl.FLOAT, false, 0, 0);
    let ib = null;
    if (indices) {
      ib = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW);
    }
    gl.bindVertexArray(null);
    this.items.set(name, { vao, vb, ib, mode, color, size,
      count: indices ? indices.length : positions.length / 3 });
  }

  remove(name) {
    const it = this.items.get(name);
    if (!it) return;
    const gl = this.gl;
    gl.deleteVertexArray(it.vao);
    gl.deleteBuffer(it.vb);
    if (it.ib) gl.deleteBuffer(it.ib);
    this.items.delete(name);
  }

  draw(camera, width, height) {
    if (!this.items.size) return;
    const gl = this.gl;
    gl.viewport(0, 0, width, height);
    gl.disable(gl.DEPTH_TEST);
    gl.enable(gl.BLEND);
    gl.blendFuncSeparate(gl.ONE, gl.ONE_MINUS_SRC_ALPHA, gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(this.prog);
    const mvp = camera.projectionMatrix.clone().multiply(camera.matrixWorldInverse);
    gl.uniformMatrix4fv(this.u.u_mvp, false, mvp.elements);
    for (const it of this.items.values()) {
      gl.uniform4fv(this.u.u_color, it.color);
      gl.uniform1f(this.u.u_size, it.size);
      gl.bindVertexArray(it.vao);
      const mode = gl[it.mode];
      if (it.ib) gl.drawElements(mode, it.count, gl.UNSIGNED_INT, 0);
      else gl.drawArrays(mode, 0, it.count);
    }
    gl.bindVertexArray(null);
  }
}
