// splatreel web player: a native 4D (keyframed, skinned) Gaussian splatting model in WebGL2, no build step, no
// network.
//
// The model is evaluated at time t in the vertex shader with the desktop renderer's formulas
// (splatreel shaders/splat_preprocess.glsl and splat_draw.glsl):
//   * native 4D Gaussians (Yang et al., ICLR 2024): mean mu_x + v (t - mu_t) + a (t - mu_t)^2 / 2 (a: the model's
//     accelerations, Spacetime Gaussians' quadratic motion, Li et al. CVPR 2024; 0 without), constant conditional
//     covariance (stored as scales + rotation), opacity sigmoid(o) exp(-(t - mu_t)^2 / (2 Sigma_tt)), culled at or
//     below TEMPORAL_CULL; colour = SH with cosine time terms cos(2 pi n (mu_t - t) / T), + 0.5, clamped at 0;
//   * keyframed models: lerp of means, scales, opacities and SH, slerp of rotations between the keys around t;
//   * skinned models (SC-GS, Huang et al. CVPR 2024): native 4D Gaussians whose canonical means and covariances
//     are carried by their 4 control nodes (linear blend skinning), the nodes' poses at t computed here per
//     displayed time (skinning.js) into a small texture;
//   * EWA splatting (Zwicker et al. 2001) as in Kerbl et al., "3D Gaussian Splatting" (2023): Jacobian at the
//     clamped x/z, y/z, + EPS2D px^2, cut where alpha < ALPHA_THRESHOLD, alpha clamped at MAX_ALPHA.
// A Web Worker sorts the Gaussians back to front by their depth at t (a 16-bit counting sort over the depth range)
// whenever the view or t changed; the splats are drawn as instanced quads, premultiplied, blended with "over"
// (Porter and Duff 1984).
//
// URL parameters: t=<model time>, cam=<c2w 4x4 or 3x4, row-major, OpenCV axes (x right, y down, z forward)>,
// eye=x,y,z & target=x,y,z (instead of cam), fov=<vertical degrees>, up=x|y|z, paused=1, ui=0, speed=<units/s>,
// loop=0.
"use strict";

(function () {
  const msg = document.getElementById("msg");
  const fail = (text) => { msg.textContent = text; console.error("splatreel-web: " + text); };
  window.addEventListener("error", (e) => fail(String(e.message || e)));

  // ---------------------------------------------------------------------------------------------- data file --
  async function loadBytes() {
    const inline = document.getElementById("splat-data");
    if (inline) {
      const text = atob(inline.textContent.trim());
      const bytes = new Uint8Array(text.length);
      for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
      return bytes.buffer;
    }
    let response;
    try {
      response = await fetch("splats.bin");
    } catch (e) {
      throw new Error("cannot read splats.bin (" + e.message + "): browsers do not let a page opened from a file " +
                      "read its neighbours; serve the folder (python -m http.server) or export with --single-file");
    }
    if (!response.ok) throw new Error("splats.bin: HTTP " + response.status);
    return response.arrayBuffer();
  }

  function parse(buffer) {
    const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, 4));
    if (magic !== "SRWB") throw new Error("not a splatreel web data file");
    const length = new DataView(buffer).getUint32(4, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, length)));
    const base = 8 + length;
    const arrays = {};
    for (const [name, a] of Object.entries(header.arrays)) {
      const type = { f32: Float32Array, f16: Uint16Array, u8: Uint8Array }[a.type];
      arrays[name] = new type(buffer, base + a.offset, a.bytes / type.BYTES_PER_ELEMENT);
    }
    return { header, arrays };
  }

  function halfToFloat(h) {
    const s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 0x1f, f = h & 0x3ff;
    if (e === 0) return s * f * Math.pow(2, -24);
    if (e === 31) return f ? NaN : s * Infinity;
    return s * (1 + f / 1024) * Math.pow(2, e - 15);
  }

  // ---------------------------------------------------------------------------------------------- shaders ----
  const VERTEX = SPLATREEL_VERTEX, FRAGMENT = SPLATREEL_FRAGMENT;  // shaders.js

  function compile(gl, defines) {
    const head = "#version 300 es\nprecision highp float;\nprecision highp int;\n" +
      Object.entries(defines).map(([k, v]) => `#define ${k} ${v}\n`).join("");
    const shader = (type, src) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, head + src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
      return s;
    };
    const prog = gl.createProgram();
    gl.attachShader(prog, shader(gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("link: " + gl.getProgramInfoLog(prog));
    return prog;
  }

  function texture(gl, unit, a, data) {
    const tex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0 + unit);
    gl.bindTexture(gl.TEXTURE_2D, tex);
    for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
    for (const p of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T]) gl.texParameteri(gl.TEXTURE_2D, p, gl.CLAMP_TO_EDGE);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    const [w, h] = a.size;
    const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    if (w > max || h > max) throw new Error(`the model needs a ${w}x${h} texture; this browser allows ${max}x${max}`);
    const fmt = { f32: [gl.RGBA32F, gl.FLOAT], f16: [gl.RGBA16F, gl.HALF_FLOAT], u8: [gl.RGBA8, gl.UNSIGNED_BYTE] };
    const [internal, type] = fmt[a.type];
    gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, gl.RGBA, type, data);
    return tex;
  }

  // ------------------------------------------------------------------------------------------- sort worker ----
  // Runs in the worker (built from this function's source): depth at t of every Gaussian that can show, then a
  // 16-bit counting sort, far to near (ties in index order).
  function sortWorker() {
    let model = null;
    let counts = new Uint32Array(65536);
    self.onmessage = (e) => {
      const m = e.data;
      if (m.model) { model = m.model; return; }
      const { rot, tz, t, key0, key1, w, poses } = m;
      const carried = [0, 0, 0];
      const n = model.count, c = model.constants;
      const depth = new Float32Array(n);
      const live = new Uint32Array(n);
      let count = 0, lo = Infinity, hi = -Infinity;
      for (let i = 0; i < n; i++) {
        let x, y, z;
        if (model.kind === "keyframed") {
          const a = 3 * (key0 * n + i), b = 3 * (key1 * n + i);
          const op = (1 - w) * model.opacity[key0 * n + i] + w * model.opacity[key1 * n + i];
          if (!(op > 0 && op >= c.ALPHA_THRESHOLD)) continue;
          x = (1 - w) * model.pos[a] + w * model.pos[b];
          y = (1 - w) * model.pos[a + 1] + w * model.pos[b + 1];
          z = (1 - w) * model.pos[a + 2] + w * model.pos[b + 2];
        } else {
          const q = 12 * i, p = model.pos, dt = t - p[q + 3];
          const marginal = Math.exp(-dt * dt * p[q + 7]);
          if (!(marginal > c.TEMPORAL_CULL) || !(p[q + 8] * marginal >= c.ALPHA_THRESHOLD)) continue;
          x = p[q] + (p[q + 4] + 0.5 * p[q + 9] * dt) * dt;
          y = p[q + 1] + (p[q + 5] + 0.5 * p[q + 10] * dt) * dt;
          z = p[q + 2] + (p[q + 6] + 0.5 * p[q + 11] * dt) * dt;
          if (poses) {  // skinned: the canonical mean carried by the nodes (skinning.js, prepended to this source)
            splatreelCarry(poses, model.skin, i, p[q], p[q + 1], p[q + 2], carried);
            [x, y, z] = carried;
          }
        }
        const d = rot[0] * x + rot[1] * y + rot[2] * z + tz;
        if (!(d > c.NEAR_PLANE)) continue;
        depth[count] = d;
        live[count++] = i;
        if (d < lo) lo = d;
        if (d > hi) hi = d;
      }
      const scale = hi > lo ? 65535 / (hi - lo) : 0;
      counts.fill(0);
      const bucket = new Uint16Array(count);
      for (let k = 0; k < count; k++) { bucket[k] = Math.floor((hi - depth[k]) * scale); counts[bucket[k]]++; }
      for (let s = 0, b = 0; b < 65536; b++) { const v = counts[b]; counts[b] = s; s += v; }
      const order = new Uint32Array(Math.max(count, 1));
      for (let k = 0; k < count; k++) order[counts[bucket[k]]++] = live[k];
      self.postMessage({ id: m.id, order, count }, [order.buffer]);
    };
  }

  // ------------------------------------------------------------------------------------------------ camera ----
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => mul(a, 1 / Math.hypot(a[0], a[1], a[2]));
  const UP = { x: [1, 0, 0], y: [0, 1, 0], z: [0, 0, 1] };
  // the orbit plane's axes (e1 x e2 = up)
  const PLANE = { x: [[0, 1, 0], [0, 0, 1]], y: [[0, 0, 1], [1, 0, 0]], z: [[1, 0, 0], [0, 1, 0]] };

  // camera-to-world (OpenCV axes) columns right, down, forward, eye: as splatreel.cameras.look_at_c2w
  function lookAt(eye, target, up) {
    const fwd = norm(sub(target, eye));
    let right = cross(fwd, up);
    if (Math.hypot(...right) < 1e-9) right = cross(fwd, [up[2], up[0], up[1]]);
    right = norm(right);
    const down = cross(fwd, right);
    return { right, down, fwd, eye };
  }

  function numbers(text, n) {
    if (text === null) return null;
    const v = text.split(",").map(Number);
    if (!n.includes(v.length) || !v.every(Number.isFinite)) throw new Error(`bad URL value ${text}`);
    return v;
  }

  // ------------------------------------------------------------------------------------------------- main -----
  async function main() {
    const params = new URLSearchParams(location.search);
    const { header: H, arrays } = parse(await loadBytes());
    const canvas = document.getElementById("view");
    const gl = canvas.getContext("webgl2", { alpha: false, antialias: false, depth: false,
                                             preserveDrawingBuffer: true, premultipliedAlpha: false });
    if (!gl) throw new Error("this browser has no WebGL2");
    const keyed = H.kind === "keyframed", skinned = H.kind === "skinned";
    const C = H.constants;
    const texels = H.geom_texels || 4;  // geometry texels per Gaussian (and key): 5 with accelerations, 6 skinned
    const defines = { SH_DEGREE: H.sh_degree, SH_DEGREE_T: H.sh_degree_t, SH_TEXELS: H.sh_texels,
                      GEOM_W: H.arrays.geom.size[0], SH_W: H.arrays.sh.size[0], GEOM_TEXELS: texels };
    // GLSL float literals (toPrecision always writes a decimal point here); TILE_SIZE stays an int
    for (const [k, v] of Object.entries(C)) defines[k] = k === "TILE_SIZE" ? Math.round(v) : v.toPrecision(17);
    if (keyed) defines.KEYFRAMED = 1;
    else if (skinned) defines.SKINNED = 1;
    else if (texels === 5) defines.ACCELERATED = 1;
    if (H.arrays.sh.type === "u8") defines.SH_U8 = 1;
    const prog = compile(gl, defines);
    gl.useProgram(prog);
    const U = (name) => gl.getUniformLocation(prog, name);
    texture(gl, 0, H.arrays.geom, arrays.geom);
    texture(gl, 1, H.arrays.sh, arrays.sh);
    gl.uniform1i(U("u_geom"), 0);
    gl.uniform1i(U("u_sh"), 1);
    gl.uniform1f(U("u_duration"), H.duration);
    gl.uniform1i(U("u_count"), H.count);
    if (H.arrays.sh.type === "u8") {
      gl.uniform4fv(U("u_sh_lo"), new Float32Array(H.arrays.sh.lo));
      gl.uniform4fv(U("u_sh_step"), new Float32Array(H.arrays.sh.step));
    }

    const nodes = skinned && splatreelNodeTexture(gl, 2, H, arrays, texture);  // (skinning.js)
    if (skinned) gl.uniform1i(U("u_nodes"), 2);

    // what the sort worker needs, as float32: native [x y z mu_t vx vy vz 1/(2 Sigma_tt) opacity ax ay az] per
    // Gaussian (a = 0 without accelerations) and a skinned model's skin [4 nodes, 4 weights]; keyframed: every
    // key's means and opacities
    const g = arrays.geom, stride = 4 * texels;
    const value = H.arrays.geom.type === "f16" ? (k) => halfToFloat(g[k]) : (k) => g[k];
    const rows = H.count * H.keys;
    let sortModel;
    if (keyed) {
      const pos = new Float32Array(3 * rows), opacity = new Float32Array(rows);
      for (let r = 0; r < rows; r++) {
        for (let k = 0; k < 3; k++) pos[3 * r + k] = value(stride * r + k);
        opacity[r] = value(stride * r + 3);
      }
      sortModel = { kind: H.kind, count: H.count, constants: C, pos, opacity };
    } else {
      const pos = new Float32Array(12 * rows), skin = skinned ? new Float32Array(8 * rows) : null;
      for (let r = 0; r < rows; r++) {
        for (let k = 0; k < 8; k++) pos[12 * r + k] = value(stride * r + k);
        pos[12 * r + 8] = value(stride * r + 15);
        if (texels === 5) for (let k = 0; k < 3; k++) pos[12 * r + 9 + k] = value(stride * r + 16 + k);
        if (skinned) for (let k = 0; k < 8; k++) skin[8 * r + k] = value(stride * r + 16 + k);
      }
      sortModel = { kind: H.kind, count: H.count, constants: C, pos, skin };
    }
    const source = splatreelCarry.toString() + "\n(" + sortWorker.toString() + ")()";
    const worker = new Worker(URL.createObjectURL(new Blob([source], { type: "text/javascript" })));
    worker.postMessage({ model: sortModel });

    // instance attribute: the Gaussian index, in drawing order
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const indexBuffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, indexBuffer);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribIPointer(0, 1, gl.UNSIGNED_INT, 0, 0);
    gl.vertexAttribDivisor(0, 1);
    let drawCount = 0;

    // ---- state: time, camera, playback
    const [t0, t1] = H.time_range;
    const upName = (params.get("up") || H.up || "y").toLowerCase();
    if (!UP[upName]) throw new Error("up must be x, y or z");
    const up = UP[upName], [e1, e2] = PLANE[upName];
    const state = { t: t0, playing: true, speed: 1, loop: true, fov: H.view.fov, pose: null,
                    target: H.view.target, dist: 1, az: 0, el: 0 };
    function setOrbit(eye, target) {
      const d = sub(eye, target);
      state.target = target;
      state.dist = Math.max(Math.hypot(...d), 1e-6);
      state.el = Math.asin(Math.max(-1, Math.min(1, dot3(d, up) / state.dist)));
      state.az = Math.atan2(dot3(d, e2), dot3(d, e1));
    }
    function reset() {
      state.pose = null;
      state.fov = Number(params.get("fov") || H.view.fov);
      const eye = numbers(params.get("eye"), [3]), target = numbers(params.get("target"), [3]);
      setOrbit(eye || H.view.eye, target || H.view.target);
      const cam = numbers(params.get("cam"), [12, 16]);
      if (cam) {  // exact pose until the user moves the view
        const col = (j) => [cam[j], cam[4 + j], cam[8 + j]];
        state.pose = { right: col(0), down: col(1), fwd: col(2), eye: col(3) };
        const far = Math.hypot(...sub(H.view.target, col(3)));
        setOrbit(col(3), add(col(3), mul(col(2), far)));
      }
      dirty = true;
    }
    function pose() {
      if (state.pose) return state.pose;
      const c = Math.cos(state.el);
      const dir = add(add(mul(e1, c * Math.cos(state.az)), mul(e2, c * Math.sin(state.az))),
                      mul(up, Math.sin(state.el)));
      return lookAt(add(state.target, mul(dir, state.dist)), state.target, up);
    }

    let dirty = true, pending = null, sortedKey = null, requestId = 0, ready = false;
    function viewKey(P) { return [P.right, P.down, P.fwd, P.eye].flat().join(",") + "|" + canvas.width; }
    function keys(t) {  // keyframed: the keys around t and the weight of the second (KeyframedGaussians._bracket)
      const kt = H.key_times, f = kt.length;
      if (f <= 1 || t <= kt[0]) return [0, 0, 0];
      if (t >= kt[f - 1]) return [f - 1, f - 1, 0];
      let i = 0;
      while (kt[i + 1] <= t) i++;
      return [i, i + 1, (t - kt[i]) / (kt[i + 1] - kt[i])];
    }
    function requestSort(P, key) {
      if (pending) return;
      const [key0, key1, w] = keys(state.t);
      const tz = -dot3(P.fwd, P.eye);
      pending = { id: ++requestId, key };
      worker.postMessage({ id: requestId, rot: P.fwd, tz, t: state.t, key0, key1, w,
                           poses: skinned ? nodes.at(state.t) : null });
    }
    worker.onmessage = (e) => {
      const { order, count } = e.data;
      gl.bindBuffer(gl.ARRAY_BUFFER, indexBuffer);
      gl.bufferData(gl.ARRAY_BUFFER, order, gl.DYNAMIC_DRAW);
      drawCount = count;
      sortedKey = pending.key;
      pending = null;
      dirty = true;
    };
    worker.onerror = (e) => fail("sort worker: " + e.message);

    function resize() {
      const dpr = window.devicePixelRatio || 1;
      const w = Math.max(1, Math.round(canvas.clientWidth * dpr));
      const h = Math.max(1, Math.round(canvas.clientHeight * dpr));
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; dirty = true; }
    }

    const bg = H.background;
    function draw(P) {
      const W = canvas.width, Hh = canvas.height;
      const f = 0.5 * Hh / Math.tan(0.5 * state.fov * Math.PI / 180);
      // w2c rotation = transpose of the c2w columns: its rows are right, down, fwd; column-major upload
      const R = [P.right, P.down, P.fwd];
      const rot = new Float32Array([R[0][0], R[1][0], R[2][0], R[0][1], R[1][1], R[2][1], R[0][2], R[1][2], R[2][2]]);
      gl.viewport(0, 0, W, Hh);
      gl.clearColor(bg[0], bg[1], bg[2], 1);
      gl.clear(gl.COLOR_BUFFER_BIT);
      gl.useProgram(prog);
      gl.uniformMatrix3fv(U("u_rot"), false, rot);
      gl.uniform3f(U("u_trans"), -dot3(P.right, P.eye), -dot3(P.down, P.eye), -dot3(P.fwd, P.eye));
      gl.uniform3fv(U("u_campos"), P.eye);
      gl.uniform4f(U("u_intr"), f, f, W / 2, Hh / 2);
      gl.uniform2f(U("u_size"), W, Hh);
      gl.uniform1f(U("u_height"), Hh);
      gl.uniform1f(U("u_time"), state.t);
      if (skinned) nodes.at(state.t);
      const [key0, key1, w] = keys(state.t);
      gl.uniform1i(U("u_key0"), key0);
      gl.uniform1i(U("u_key1"), key1);
      gl.uniform1f(U("u_w"), w);
      if (drawCount > 0) {
        gl.enable(gl.BLEND);
        gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);  // premultiplied, back to front
        gl.bindVertexArray(vao);
        gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, drawCount);
      }
    }

    // ---- UI
    const $ = (id) => document.getElementById(id);
    const bar = $("bar"), slider = $("time"), play = $("play"), speed = $("speed"), loop = $("loop");
    slider.min = t0; slider.max = t1;
    if (params.get("ui") !== "0") bar.classList.remove("hidden");
    const setPlaying = (on) => { state.playing = on; play.textContent = on ? "Pause" : "Play"; };
    play.onclick = () => {
      if (!state.playing && state.t >= t1) state.t = t0;  // play again from the start
      setPlaying(!state.playing);
      dirty = true;
    };
    slider.oninput = () => { state.t = Number(slider.value); dirty = true; };
    speed.onchange = () => { state.speed = Number(speed.value); };
    loop.onchange = () => { state.loop = loop.checked; };
    $("reset").onclick = () => reset();
    $("link").onclick = () => {  // this view and time as URL parameters (the pose exactly, c2w row-major)
      const P = pose(), q = new URLSearchParams(location.search);
      const c2w = [0, 1, 2].flatMap((r) => [P.right[r], P.down[r], P.fwd[r], P.eye[r]]).concat([0, 0, 0, 1]);
      for (const k of ["eye", "target"]) q.delete(k);
      q.set("t", String(state.t));
      q.set("cam", c2w.map((v) => +v.toPrecision(9)).join(","));
      q.set("fov", String(state.fov));
      q.set("paused", "1");
      history.replaceState(null, "", "?" + q.toString().replace(/%2C/g, ","));
    };
    window.addEventListener("keydown", (e) => {
      if (e.key === " ") { play.onclick(); e.preventDefault(); } else if (e.key === "r") reset();
    });

    // orbit (left drag / one finger), pan (right or shift drag / two fingers), zoom (wheel / pinch)
    const pointers = new Map();
    let pinch = null;
    const moved = () => { state.pose = null; dirty = true; };
    function panBy(dx, dy) {
      const P = pose(), f = 0.5 * canvas.clientHeight / Math.tan(0.5 * state.fov * Math.PI / 180);
      state.target = add(state.target, add(mul(P.right, -dx * state.dist / f), mul(P.down, -dy * state.dist / f)));
    }
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("pointerdown", (e) => {
      canvas.setPointerCapture(e.pointerId);
      pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey });
    });
    canvas.addEventListener("pointermove", (e) => {
      const p = pointers.get(e.pointerId);
      if (!p) return;
      const dx = e.clientX - p.x, dy = e.clientY - p.y;
      if (pointers.size === 1) {
        if (state.pose) setOrbitFromPose();
        if (p.pan) panBy(dx, dy);
        else {
          state.az -= dx * 0.005;
          state.el = Math.max(-1.55, Math.min(1.55, state.el + dy * 0.005));
        }
      } else if (pointers.size === 2) {
        const [a, b] = [...pointers.values()];
        const mid0 = [(a.x + b.x) / 2, (a.y + b.y) / 2], span0 = Math.hypot(a.x - b.x, a.y - b.y);
        p.x = e.clientX; p.y = e.clientY;
        const mid1 = [(a.x + b.x) / 2, (a.y + b.y) / 2], span1 = Math.hypot(a.x - b.x, a.y - b.y);
        if (state.pose) setOrbitFromPose();
        panBy(mid1[0] - mid0[0], mid1[1] - mid0[1]);
        if (span0 > 0 && span1 > 0) state.dist *= span0 / span1;
      }
      p.x = e.clientX; p.y = e.clientY;
      moved();
    });
    const up_ = (e) => { pointers.delete(e.pointerId); pinch = null; };
    canvas.addEventListener("pointerup", up_);
    canvas.addEventListener("pointercancel", up_);
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      if (state.pose) setOrbitFromPose();
      state.dist *= Math.exp(e.deltaY * 0.001);
      moved();
    }, { passive: false });
    function setOrbitFromPose() {  // keep the current pose's eye and direction, then orbit about its target
      const P = state.pose;
      setOrbit(P.eye, add(P.eye, mul(P.fwd, state.dist)));
      state.pose = null;
    }

    // ---- URL state
    reset();
    if (params.has("t")) state.t = Math.max(t0, Math.min(t1, Number(params.get("t"))));
    if (params.has("speed")) { state.speed = Number(params.get("speed")); speed.value = String(state.speed); }
    if (params.get("loop") === "0") { state.loop = false; loop.checked = false; }
    setPlaying(params.get("paused") !== "1" && t1 > t0);

    // ---- frame loop: advance time, re-sort when the view or t changed, draw when anything changed
    let last = null, frames = 0, fpsStart = performance.now();
    function frame(now) {
      resize();
      if (state.playing && last !== null) {
        let t = state.t + state.speed * (now - last) / 1000;
        if (t > t1) {
          if (state.loop && t1 > t0) t = t0 + ((t - t0) % (t1 - t0));
          else { t = t1; setPlaying(false); }
        }
        state.t = t;
        dirty = true;
      }
      last = now;
      const P = pose();
      const key = viewKey(P) + "|" + state.t;
      if (key !== sortedKey) requestSort(P, key);
      if (dirty) {
        draw(P);
        dirty = false;
        frames++;
        slider.value = state.t;
        $("tlabel").textContent = "t = " + state.t.toFixed(3);
        // for scripts and tests: frames drawn, whether the last one used the order at its view and time
        const root = document.documentElement.dataset;
        root.frames = String(Number(root.frames || 0) + 1);
        root.sorted = key === sortedKey ? "1" : "0";
        if (!ready && key === sortedKey) {
          ready = true;
          root.ready = "1";
          console.log(`splatreel-web: ready (${H.count} Gaussians, ${drawCount} drawn, t = ${state.t})`);
        }
      }
      if (now - fpsStart >= 1000) {
        // frames drawn per second (none while nothing changes)
        $("fps").textContent = frames ? (1000 * frames / (now - fpsStart)).toFixed(1) + " FPS" : "idle";
        frames = 0;
        fpsStart = now;
      }
      requestAnimationFrame(frame);
    }
    requestAnimationFrame(frame);
  }

  main().catch((e) => fail(e && e.message ? e.message : String(e)));
})();
