// The web player's control nodes of a skinned model (splatreel.skinned.SkinnedGaussians; linear blend skinning as
// in SC-GS, Huang et al., "SC-GS: Sparse-Controlled Gaussian Splatting for Editable Dynamic Scenes", CVPR 2024).
// Loaded before player.js. The page's one copy in JavaScript of splatreel.skinned.node_poses (here) and of
// splatreel.skinned.carry (for the depth sort; the vertex shader carries with shaders/splat_skin.glsl).
"use strict";

// Every node's pose at time t, as the node texture's texels (shaders/splat_skin.glsl): node k's 4 RGBA texels are
// its rotation's rows 0-2 with its position's x, y, z in w, then its canonical position. `nodes`: { count M,
// times [F], canonical [M * 3], positions [F * M * 3], rotations [F * M * 4] (w first, unnormalised) }.
// Between the keys around t the positions follow the uniform Catmull-Rom spline (a missing neighbour key at either
// end is the reflection of the next key across the end one) and the rotations a normalised lerp along the shorter
// arc; t is clamped to the keys, so the end poses hold outside them (splatreel.skinned.key_segments, catmull_rom,
// spline_segment, nlerp). With one key the clamped indices give that key's pose.
function splatreelNodePoses(nodes, t) {
  const M = nodes.count, times = nodes.times, F = times.length, last = F - 1;
  const P = nodes.positions, Q = nodes.rotations, C = nodes.canonical;
  let i = 0, u = 0;
  if (F > 1) {  // the key segment [times[i], times[i + 1]] holding t, and the share u of the way through it
    const tc = Math.min(Math.max(t, times[0]), times[last]);
    while (i < F - 2 && times[i + 1] <= tc) i++;
    u = (tc - times[i]) / (times[i + 1] - times[i]);
  }
  const key = (d) => Math.min(Math.max(i + d, 0), last);
  const [k0, k1, k2, k3] = [key(-1), key(0), key(1), key(2)];
  const before = i > 0, after = i + 2 <= last;
  const out = new Float32Array(16 * M);
  for (let k = 0; k < M; k++) {
    for (let a = 0; a < 3; a++) {
      const at = (f) => P[(f * M + k) * 3 + a];
      const p1 = at(k1), p2 = at(k2);
      const p0 = before ? at(k0) : 2 * p1 - p2, p3 = after ? at(k3) : 2 * p2 - p1;
      out[16 * k + 4 * a + 3] = 0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u * u
                                       + (3 * p1 - p0 - 3 * p2 + p3) * u * u * u);
      out[16 * k + 12 + a] = C[3 * k + a];
    }
    const qi = [0, 1, 2, 3].map((c) => Q[(k1 * M + k) * 4 + c]);
    let qj = [0, 1, 2, 3].map((c) => Q[(k2 * M + k) * 4 + c]);
    if (qi[0] * qj[0] + qi[1] * qj[1] + qi[2] * qj[2] + qi[3] * qj[3] < 0) qj = qj.map((v) => -v);
    const q = qi.map((v, c) => v * (1 - u) + qj[c] * u);
    const n = Math.max(Math.hypot(q[0], q[1], q[2], q[3]), 1e-12);
    const [w, x, y, z] = q.map((v) => v / n);  // splatreel.quaternion.to_rotmat, by rows
    out.set([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 16 * k);
    out.set([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 16 * k + 4);
    out.set([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 16 * k + 8);
  }
  return out;
}

// The carried mean of canonical mean (x, y, z), sum_k w_k (R_k (x - c_k) + p_k), into out[0..2]: Gaussian i's
// nodes skin[8 i .. 8 i + 3] with weights skin[8 i + 4 .. 8 i + 7] (renormalised, as splat_skin.glsl does), and the
// node texels `poses` of splatreelNodePoses. The sort worker's (its source is prepended to the worker's).
function splatreelCarry(poses, skin, i, x, y, z, out) {
  const s = 8 * i, total = skin[s + 4] + skin[s + 5] + skin[s + 6] + skin[s + 7];
  out[0] = out[1] = out[2] = 0;
  for (let k = 0; k < 4; k++) {
    const n = 16 * Math.round(skin[s + k]), w = skin[s + 4 + k] / total;
    const dx = x - poses[n + 12], dy = y - poses[n + 13], dz = z - poses[n + 14];
    for (let r = 0; r < 3; r++) {
      const row = n + 4 * r;
      out[r] += w * (poses[row] * dx + poses[row + 1] * dy + poses[row + 2] * dz + poses[row + 3]);
    }
  }
}

// A skinned model's node texture on texture unit `unit`, made with the player's texture(gl, unit, array, data)
// from the header's node_count and node_times and the arrays node_canonical, node_positions, node_rotations:
// at(t) poses the nodes at t (once per new t) and returns the texels.
function splatreelNodeTexture(gl, unit, header, arrays, texture) {
  const nodes = { count: header.node_count, times: header.node_times, canonical: arrays.node_canonical,
                  positions: arrays.node_positions, rotations: arrays.node_rotations };
  let t0 = header.time_range[0], texels = splatreelNodePoses(nodes, t0);
  const tex = texture(gl, unit, { type: "f32", size: [4, nodes.count] }, texels);
  return {
    at(t) {
      if (t !== t0) {
        t0 = t;
        texels = splatreelNodePoses(nodes, t);
        gl.activeTexture(gl.TEXTURE0 + unit);
        gl.bindTexture(gl.TEXTURE_2D, tex);
        gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 4, nodes.count, gl.RGBA, gl.FLOAT, texels);
      }
      return texels;
    },
  };
}
