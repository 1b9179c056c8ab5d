#version 330 core
// Per-Gaussian pre-pass: evaluates each Gaussian at time t and projects it, once per Gaussian (not per quad
// corner). Drawn as GL_POINTS through an index buffer holding the back-to-front order, with rasterizer discard;
// transform feedback writes one 48-byte record per drawn index, in that order, for splat_draw.glsl.
//
// Math (one place each, mirrored here): splatreel.covariance (conditional mean moving linearly in t, plus
// splatreel.model's acceleration term, constant
// conditional covariance, unnormalised temporal marginal and its TEMPORAL_CULL), splatreel.sh (SH degrees 0-3 with
// cosine time terms, colour = max(SH + 0.5, 0), view direction from the sliced mean), and the trainer's EWA
// projection (OpenCV camera, Jacobian at x/z, y/z clamped to the image plus (FRUSTUM_CLAMP - 1) tan_fov on each
// side, + EPS2D px^2, near-plane cull), and its footprint rule: the tiles (TILE_SIZE) of the square box of radius
// ceil(RADIUS_SIGMAS sqrt(lambda_max)) (EIGEN_FLOOR under the discriminant), intersected with the alpha >=
// ALPHA_THRESHOLD ellipse, optionally capped (splatreel.viewer.sorting.Footprint). A skinned model (SKINNED 1,
// splatreel.skinned.SkinnedGaussians.slice): the Gaussian's canonical mean (the conditional mean at mu_t, which the
// native velocity does not move) and conditional covariance carried by its 4 nodes (splat_skin.glsl), the temporal
// opacity and the colour native.
//
// Compile-time defines (splatreel.viewer.renderer): SH_DEGREE, SH_DEGREE_T, SH_TEXELS (RGBA texels per Gaussian),
// SH_TEX_WIDTH (texels per row of the SH texture), TILE_SIZE, SKINNED (0 or 1). Rendering constants come from
// splatreel.constants.

#if defined VERTEX_SHADER

in vec4 a_mean_t;   // mean xyz at the temporal mean, temporal mean mu_t
in vec4 a_motion;   // velocity xyz, 1 / (2 Sigma_tt) (0: no temporal fade)
in vec4 a_accel;    // acceleration xyz (0: linear motion; splatreel.model.Gaussians4D.accelerations), w unused
in vec4 a_cov_a;    // conditional covariance c00 c01 c02 c11
in vec4 a_cov_b;    // c12 c22, opacity, speed |d mean / dt|
#if SKINNED
in vec4 a_skin_nodes;    // the Gaussian's 4 nodes (indices into u_nodes' rows)
in vec4 a_skin_weights;  // their blend weights
uniform float u_skin_step;  // 2 h: the time between pose sets 1 (t - h) and 2 (t + h) of u_nodes
#include "splat_skin.glsl"
#endif

uniform mat3 u_rot;         // world -> camera rotation (OpenCV axes)
uniform vec3 u_trans;       // world -> camera translation
uniform vec3 u_campos;      // camera centre in world space
uniform vec4 u_intrinsics;  // fx fy cx cy (pixels)
uniform vec2 u_size;        // image width, height (pixels)
uniform float u_time;       // model time t
uniform float u_duration;   // T = t1 - t0 (period scale of the colour's time terms)
uniform float u_scale;      // splat scale (multiplies every std-dev)
uniform vec2 u_max_radius;  // footprint caps: std-devs, pixels along the major axis (sorting.footprint_caps)
uniform float u_near;       // near plane (camera depth; sorting.Footprint.near_plane, NEAR_PLANE by default)
uniform bool u_smooth_fade; // temporal fade "smooth" (splatreel.covariance.temporal_factor), else "cut"
uniform int u_sh_degree;    // displayed SH degree (<= SH_DEGREE)
uniform sampler2D u_sh;     // packed colour coefficients, SH_TEXELS RGBA texels per Gaussian
uniform int u_value;        // what o_color.rgb holds: 0 the SH colour, 1 the depth z, 2 the speed |d mean / dt|,
                            // 3 the visible time span (splatreel.covariance.visible_span), at most u_duration,
                            // 4 the factor on the opacity at t (the temporal marginal, in (TEMPORAL_CULL, 1],
                            // faded to 0 at the cull with the smooth temporal fade)

out vec4 o_geom;   // centre x, y (pixels, y down), footprint radius in std-devs (0 = culled; capped), depth z
out vec4 o_axes;   // 2D principal axes scaled by their std-devs (pixels): axis 1 xy, axis 2 xy
out vec4 o_color;  // rgb (the value of a value mode, u_value, in all three), opacity at t
out vec4 o_rect;   // pixels the reference rasterizer may touch: x0, y0, x1, y1 (tile-aligned, end exclusive)

const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                                -0.4570457994644658, 1.445305721320277, -0.5900435899266435);
const float TWO_PI = 6.283185307179586;

#define SH_BASES ((SH_DEGREE + 1) * (SH_DEGREE + 1))

#include "splat_footprint.glsl"

void cull() {
    o_geom = vec4(0.0);
    o_axes = vec4(0.0);
    o_color = vec4(0.0);
    o_rect = vec4(0.0);
}

// Colour of this Gaussian seen along `dir` at tau = mu_t - t (splatreel.sh.collapse_time + eval_sh + sh_to_rgb).
vec3 sh_color(vec3 dir, float tau) {
    float c[SH_TEXELS * 4];
    int base = gl_VertexID * SH_TEXELS;
    for (int k = 0; k < SH_TEXELS; ++k) {
        int texel = base + k;
        vec4 v = texelFetch(u_sh, ivec2(texel % SH_TEX_WIDTH, texel / SH_TEX_WIDTH), 0);
        c[4 * k] = v.x;
        c[4 * k + 1] = v.y;
        c[4 * k + 2] = v.z;
        c[4 * k + 3] = v.w;
    }
    vec3 coef[SH_BASES];
    for (int j = 0; j < SH_BASES; ++j) {
        coef[j] = vec3(c[3 * j], c[3 * j + 1], c[3 * j + 2]);
    }
#if SH_DEGREE_T > 0
    for (int n = 1; n <= SH_DEGREE_T; ++n) {
        float w = cos(TWO_PI * float(n) * tau / u_duration);
        for (int j = 0; j < SH_BASES; ++j) {
            int k = 3 * (n * SH_BASES + j);
            coef[j] += w * vec3(c[k], c[k + 1], c[k + 2]);
        }
    }
#endif
    vec3 result = SH_C0 * coef[0];
#if SH_DEGREE >= 1
    if (u_sh_degree >= 1) {
        vec3 d = normalize(dir);
        float x = d.x, y = d.y, z = d.z;
        result += -SH_C1 * y * coef[1] + SH_C1 * z * coef[2] - SH_C1 * x * coef[3];
#if SH_DEGREE >= 2
        if (u_sh_degree >= 2) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            result += SH_C2[0] * xy * coef[4] + SH_C2[1] * yz * coef[5] + SH_C2[2] * (2.0 * zz - xx - yy) * coef[6]
                    + SH_C2[3] * xz * coef[7] + SH_C2[4] * (xx - yy) * coef[8];
#if SH_DEGREE >= 3
            if (u_sh_degree >= 3) {
                result += SH_C3[0] * y * (3.0 * xx - yy) * coef[9] + SH_C3[1] * xy * z * coef[10]
                        + SH_C3[2] * y * (4.0 * zz - xx - yy) * coef[11]
                        + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * coef[12]
                        + SH_C3[4] * x * (4.0 * zz - xx - yy) * coef[13] + SH_C3[5] * z * (xx - yy) * coef[14]
                        + SH_C3[6] * x * (xx - 3.0 * yy) * coef[15];
            }
#endif
        }
#endif
    }
#endif
    return max(result + 0.5, vec3(0.0));
}

void main() {
    // --- the 4D Gaussian at time t (splatreel.covariance.condition_on_time / temporal_marginal) -----------------
    float dt = u_time - a_mean_t.w;
    float marginal = exp(-dt * dt * a_motion.w);
    if (!(marginal > TEMPORAL_CULL)) { cull(); return; }
    // splatreel.covariance.temporal_factor: "smooth" fades the factor to 0 at the cull instead of cutting it
    float factor = u_smooth_fade ? marginal * smoothstep(TEMPORAL_CULL, 2.0 * TEMPORAL_CULL, marginal) : marginal;
    float opacity = a_cov_b.z * factor;
    if (!(opacity >= ALPHA_THRESHOLD)) { cull(); return; }
#if SKINNED
    mat3 blend;
    vec3 mean = skin_carry(a_mean_t.xyz, a_skin_nodes, a_skin_weights, 0, blend);
#else
    vec3 mean = a_mean_t.xyz + (a_motion.xyz + 0.5 * a_accel.xyz * dt) * dt;  // splatreel.model: mu + v dt + a dt^2/2
#endif

    // --- EWA projection (splat_footprint.glsl) ------------------------------------------------------------------
    vec3 p = u_rot * mean + u_trans;
    if (!(p.z > u_near)) { cull(); return; }
    float s2 = u_scale * u_scale;
    mat3 cov = s2 * mat3(a_cov_a.x, a_cov_a.y, a_cov_a.z,
                         a_cov_a.y, a_cov_a.w, a_cov_b.x,
                         a_cov_a.z, a_cov_b.x, a_cov_b.y);
#if SKINNED
    cov = blend * cov * transpose(blend);
#endif
    Footprint f;
    if (!splat_footprint(p, u_rot, cov, opacity, u_intrinsics, u_size, f)) { cull(); return; }
    // the footprint caps (off: 1e30), as sorting._depth_key: std-devs, then pixels along the major axis
    float radius = min(f.radius, min(u_max_radius.x, u_max_radius.y / sqrt(f.major)));
    vec2 centre = f.centre;
    vec2 half_box = min(vec2(f.box), radius * f.spread + 1.0);
    vec2 lo = centre - half_box, hi = centre + half_box;
    if (footprint_outside(f, half_box, u_size)) {
        cull();
        return;
    }
    vec2 axis1 = f.axis1, axis2 = f.axis2;
    o_geom = vec4(centre, max(radius, 1e-6), p.z);
    o_axes = vec4(axis1, axis2);
    // the value modes composite their value as a grey colour, so the splat shader has one path for all modes
    // the time window where the marginal exceeds the cull; capped at the model's span, so that an unfading
    // Gaussian (or a keyframed slice) reads as "throughout" instead of flooding the pixel's average
    // |d mean / dt| at t: the stored speed (a keyframed slice's, kept apart from its zero motion), or with
    // accelerations |v + a dt|; a skinned Gaussian's carried mean differenced over t -+ h (its slice's velocity)
#if SKINNED
    float speed = 0.0;
    if (u_value == 2) {
        mat3 unused;
        speed = length(skin_carry(a_mean_t.xyz, a_skin_nodes, a_skin_weights, 2, unused)
                       - skin_carry(a_mean_t.xyz, a_skin_nodes, a_skin_weights, 1, unused)) / u_skin_step;
    }
#else
    float speed = a_accel.xyz == vec3(0.0) ? a_cov_b.w : length(a_motion.xyz + a_accel.xyz * dt);
#endif
    float span = a_motion.w > 0.0 ? min(2.0 * sqrt(-log(TEMPORAL_CULL) / a_motion.w), u_duration) : u_duration;
    vec3 rgb = u_value == 0 ? sh_color(mean - u_campos, -dt)
                            : vec3(u_value == 1 ? p.z : u_value == 2 ? speed : u_value == 3 ? span : factor);
    o_color = vec4(rgb, opacity);
    o_rect = vec4(floor(lo / float(TILE_SIZE)), ceil(hi / float(TILE_SIZE))) * float(TILE_SIZE);
}

#endif
