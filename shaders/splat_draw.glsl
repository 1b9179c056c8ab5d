#version 330 core
// One splat per pre-processed Gaussian (splat_preprocess.glsl output, already in draw order). Compiled three
// ways (one define each); the first two give the same pixels and values:
//   * SPLAT_POINTS: one GL point per Gaussian, a square sprite over the bounding box of its footprint
//     ellipse. One vertex and one primitive set-up per Gaussian: on a software rasterizer (Mesa llvmpipe) that
//     is 1.4-1.6x faster than quads for typical scenes, where the per-primitive cost dominates. A point is
//     clipped by its centre, so the renderer draws points through a viewport enlarged by u_margin pixels on
//     every side (at least half the largest point): every point that can reach the image has its centre inside.
//     Points are limited in size (GL_POINT_SIZE_RANGE), so the renderer falls back to quads for stages holding
//     larger Gaussians.
//   * SPLAT_QUADS: one instanced quad spanning the Gaussian's principal axes out to the cut-off radius;
//   * SPLAT_OVERLAY: the same quads for the outline and centre modes (only this variant has their code: llvmpipe
//     runs the branches of uniform ifs as masked code, at a cost on every fragment).
// Either way the footprint reaches the pre-pass's radius: where alpha falls to ALPHA_THRESHOLD, so every pixel
// the reference rasterizer would touch is covered, unless a footprint cap (sorting.Footprint) cut it shorter.
// uv is the offset from the centre in std-devs (Mahalanobis coordinates: interpolated across a quad, which is
// exact for a linear map, or mapped back from the pixel for a point): power = -|uv|^2 / 2. Fragments past the
// radius (|uv|^2 > radius^2: alpha < ALPHA_THRESHOLD when uncapped) or outside the Gaussian's tile rectangle
// (i_rect) get alpha 0, as in the reference rasterizer.
// Output is premultiplied (rgb * alpha, alpha) into a float target cleared to 0, blended either back to front
// with (ONE, ONE_MINUS_SRC_ALPHA) or front to back with (ONE_MINUS_DST_ALPHA, ONE): both give
// rgb = sum c_i a_i T_i and alpha = 1 - prod(1 - a_i), the reference compositing. Splats sit at depth 0.5 so
// that the front-to-back early stop (splat_screen.glsl writes depth 0 over saturated pixels) rejects them there.
//
// u_mode: 3 ellipse outlines (2 sigma), 4 centres (small discs), in SPLAT_OVERLAY only; every other mode is drawn
//         the same way: colour, alpha, and depth, speed, lifespan and fade, whose value the pre-pass wrote as the
//         colour (accumulating the expected value sum v_i a_i T_i).

#define MODE_OUTLINES 3
#define MODE_CENTRES 4
#define OUTLINE_SIGMAS 2.0
#define CENTRE_RADIUS_PX 2.0

#if defined VERTEX_SHADER

in vec4 i_geom;   // centre x, y (pixels, y down), radius (std-devs, 0 = culled), depth
in vec4 i_axes;   // axis 1 xy, axis 2 xy (pixels per std-dev)
in vec4 i_color;  // rgb (the value of the depth, speed, lifespan and fade modes), opacity
in vec4 i_rect;   // tile rectangle x0, y0, x1, y1 (pixels, y down)

uniform vec2 u_size;
uniform int u_mode;
#ifdef SPLAT_POINTS
uniform float u_margin;     // the viewport reaches this many pixels past every image edge
uniform float u_max_point;  // largest point size the context draws

flat out vec2 v_centre;
flat out mat2 v_to_uv;      // pixel offset from the centre -> std-devs along the principal axes
#else
out vec2 v_uv;
#endif
flat out vec4 v_color;
flat out vec4 v_rect;
flat out float v_radius2;   // squared footprint radius (std-devs^2)

void main() {
    if (i_geom.z <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // culled: outside the clip volume
#ifdef SPLAT_POINTS
        gl_PointSize = 1.0;
#endif
        return;
    }
    vec2 a1 = i_axes.xy;
    vec2 a2 = i_axes.zw;
    float radius = i_geom.z;
#ifdef SPLAT_POINTS
    // bounding box of the ellipse {c + a1 u + a2 v : u^2 + v^2 <= radius^2}; + 1: fragments are produced for
    // pixel centres inside the square, so half a pixel of slack on each side
    vec2 half_box = radius * sqrt(a1 * a1 + a2 * a2);
    gl_PointSize = min(2.0 * max(half_box.x, half_box.y) + 1.0, u_max_point);
    vec2 px = i_geom.xy + u_margin;
    vec2 extent = u_size + 2.0 * u_margin;
    gl_Position = vec4(2.0 * px.x / extent.x - 1.0, 1.0 - 2.0 * px.y / extent.y, 0.0, 1.0);  // depth 0.5
    v_centre = i_geom.xy;
    v_to_uv = inverse(mat2(a1, a2));
#else
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
#ifdef SPLAT_OVERLAY
    if (u_mode == MODE_OUTLINES) {
        // reach the 2 sigma ring plus ~2 px for its anti-aliased edge
        radius = OUTLINE_SIGMAS + 2.0 / max(min(length(a1), length(a2)), 1e-3);
    } else if (u_mode == MODE_CENTRES) {
        a1 = vec2(CENTRE_RADIUS_PX, 0.0);
        a2 = vec2(0.0, CENTRE_RADIUS_PX);
        radius = 1.5;
    }
#endif
    vec2 uv = corner * radius;
    vec2 px = i_geom.xy + a1 * uv.x + a2 * uv.y;
    gl_Position = vec4(2.0 * px.x / u_size.x - 1.0, 1.0 - 2.0 * px.y / u_size.y, 0.0, 1.0);  // depth 0.5
    v_uv = uv;
#endif
    v_color = i_color;
    v_radius2 = i_geom.z * i_geom.z;
    v_rect = u_mode == MODE_OUTLINES || u_mode == MODE_CENTRES ? vec4(-1e30, -1e30, 1e30, 1e30) : i_rect;
}

#elif defined FRAGMENT_SHADER

uniform int u_mode;
uniform float u_height;

#ifdef SPLAT_POINTS
flat in vec2 v_centre;
flat in mat2 v_to_uv;
#else
in vec2 v_uv;
#endif
flat in vec4 v_color;
flat in vec4 v_rect;
flat in float v_radius2;

out vec4 f_color;

#include "splat_alpha.glsl"

void main() {
    vec2 pixel = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y);  // pixel centre, y down
#ifdef SPLAT_POINTS
    vec2 uv = v_to_uv * (pixel - v_centre);
#else
    vec2 uv = v_uv;
#endif
    float r2 = dot(uv, uv);
#ifdef SPLAT_OVERLAY
    if (u_mode == MODE_OUTLINES) {
        float r = sqrt(r2);
        float ring = 1.0 - smoothstep(0.0, 1.5 * fwidth(r), abs(r - OUTLINE_SIGMAS));
        float a = ring * clamp(4.0 * v_color.a, 0.2, 1.0);
        f_color = vec4(v_color.rgb * a, a);
        return;
    }
    if (u_mode == MODE_CENTRES) {
        float a = 1.0 - smoothstep(1.0 - fwidth(sqrt(r2)), 1.0, sqrt(r2));
        f_color = vec4(v_color.rgb * a, a);
        return;
    }
#endif
    // past the radius the fragment adds exactly nothing (cheaper than discard on software rasterizers)
    float alpha = splat_alpha(v_color.a, r2, v_radius2, pixel, v_rect);
    f_color = vec4(v_color.rgb * alpha, alpha);
}

#endif
