// Linear blend skinning of a skinned model's Gaussians (splatreel.skinned.carry), as in SC-GS (Huang et al.,
// "SC-GS: Sparse-Controlled Gaussian Splatting for Editable Dynamic Scenes", CVPR 2024): a Gaussian at canonical
// mean x with covariance cov, skinned to nodes k with weights w_k, is carried by its nodes' poses (p_k, R_k) at
// time t (c_k: node k's canonical position) to
//     mean' = sum_k w_k (R_k (x - c_k) + p_k),    cov' = B cov B^T,  B = sum_k w_k R_k.
// Shared by the desktop pre-pass (splat_preprocess.glsl) and the web player (export/web_player/shaders.js); no
// #version: it is a part of those programs.
// u_nodes holds node k in row k, NODE_TEXELS (4) RGBA texels per pose set: R_k's rows 0-2 with p_k's x, y, z in w,
// then c_k; the CPU computes the poses at t (splatreel.skinned.node_poses; the page's skinning.js).
uniform highp sampler2D u_nodes;

// The carried mean of canonical mean `x` (nodes: 4 indices as floats, weights: 4 blend weights) by pose set `set`;
// `blend` receives B.
vec3 skin_carry(vec3 x, vec4 nodes, vec4 weights, int set, out mat3 blend) {
    weights /= dot(weights, vec4(1.0));  // they sum to 1 already; again after half-float storage (web --quantize)
    vec3 moved = vec3(0.0);
    blend = mat3(0.0);
    for (int k = 0; k < 4; ++k) {
        int node = int(nodes[k] + 0.5);
        vec4 r0 = texelFetch(u_nodes, ivec2(4 * set, node), 0);
        vec4 r1 = texelFetch(u_nodes, ivec2(4 * set + 1, node), 0);
        vec4 r2 = texelFetch(u_nodes, ivec2(4 * set + 2, node), 0);
        vec3 c = texelFetch(u_nodes, ivec2(4 * set + 3, node), 0).xyz;
        mat3 turn = transpose(mat3(r0.xyz, r1.xyz, r2.xyz));  // GLSL's mat3 takes columns: these are rows
        moved += weights[k] * (turn * (x - c) + vec3(r0.w, r1.w, r2.w));
        blend += weights[k] * turn;
    }
    return moved;
}
