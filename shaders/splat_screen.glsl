#version 330 core
// The full-screen passes of the splat renderer, one program per SCREEN_PASS (a define set by the renderer), all
// drawn as a single triangle covering the target:
//
// SCREEN_RESOLVE (0): turns the premultiplied accumulation of splat_draw.glsl (rgb = sum c a T, alpha = 1 - T)
//     into the displayed image, stretched over the viewport u_viewport (x, y, w, h): 1:1 when the image has the
//     viewport's size (nearest filtering, exactly the image's pixels), smoothly upscaled when the app draws at a
//     lower resolution (linear filtering of the premultiplied values, which is correct for premultiplied colour);
//     composited over a premultiplied background u_background = (rgb * a, a): a = 0
//     keeps a transparent background (premultiplied colour + alpha, ready for EXR/PNG export), a = 1 gives
//     C + T * bg. u_mode: 0 colour, 1 depth (expected depth / alpha through the Turbo colour map over
//     u_value_range, near = red), 2 alpha (grey, opaque), 3 outlines and 4 centres (as colour), 5 speed and
//     6 lifespan, 7 fade (expected speed, visible time span or temporal opacity factor / alpha through the same map
//     over u_value_range, high = red).
// The other two passes map pixels 1:1 (texelFetch at gl_FragCoord).
// SCREEN_MASK (1): front-to-back early stop between batches of splats: depth 0 (the triangle's depth) wherever
//     the accumulated alpha has reached 1 - TRANSMITTANCE_THRESHOLD (the reference rasterizer stops a pixel
//     there), so the depth test (LESS, splats at depth 0.5) rejects every later fragment of that pixel before its
//     shader runs.
// SCREEN_TILES (2): which OCCLUSION_TILE x OCCLUSION_TILE pixel tiles are saturated (every pixel as above), into a
//     target with one texel per tile counted from the lower-left corner; pixels beyond the image count as
//     saturated. Read back to skip Gaussians hidden behind saturated tiles.

#define SCREEN_RESOLVE 0
#define SCREEN_MASK 1
#define SCREEN_TILES 2

#if defined VERTEX_SHADER

void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, SCREEN_PASS == SCREEN_MASK ? -1.0 : 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_accum;

#if SCREEN_PASS == SCREEN_RESOLVE

uniform vec4 u_background;   // premultiplied background colour
uniform int u_mode;
uniform vec2 u_value_range;  // depth (near, far), speed (slow, fast), lifespan (brief, long), fade: the map's ends
uniform vec4 u_viewport;     // x, y (lower-left corner), width, height of the viewport in the target

out vec4 f_color;

// Polynomial fit of Google's Turbo colour map (Mikhailov 2019, public domain fit by its author).
vec3 turbo(float x) {
    const vec4 kr4 = vec4(0.13572138, 4.61539260, -42.66032258, 132.13108234);
    const vec4 kg4 = vec4(0.09140261, 2.19418839, 4.84296658, -14.18503333);
    const vec4 kb4 = vec4(0.10667330, 12.64194608, -60.58204836, 110.36276771);
    const vec2 kr2 = vec2(-152.94239396, 59.28637943);
    const vec2 kg2 = vec2(4.27729857, 2.82956604);
    const vec2 kb2 = vec2(-89.90310912, 27.34824973);
    x = clamp(x, 0.0, 1.0);
    vec4 v4 = vec4(1.0, x, x * x, x * x * x);
    vec2 v2 = v4.zw * v4.z;
    return clamp(vec3(dot(v4, kr4) + dot(v2, kr2), dot(v4, kg4) + dot(v2, kg2), dot(v4, kb4) + dot(v2, kb2)),
                 0.0, 1.0);
}

void main() {
    vec4 acc = texture(u_accum, (gl_FragCoord.xy - u_viewport.xy) / u_viewport.zw);
    float alpha = acc.a;
    if (u_mode == 2) {
        f_color = vec4(vec3(alpha), 1.0);
        return;
    }
    vec3 rgb = acc.rgb;
    if (u_mode == 1 || u_mode >= 5) {
        float value = alpha > 1e-6 ? acc.r / alpha : u_value_range.x;
        float x = (value - u_value_range.x) / max(u_value_range.y - u_value_range.x, 1e-6);
        rgb = turbo(u_mode == 1 ? 1.0 - x : x) * alpha;  // near (depth), fast, long-lived, at its peak = red
    }
    f_color = vec4(rgb, alpha) + (1.0 - alpha) * u_background;
}

#elif SCREEN_PASS == SCREEN_MASK

void main() {
    if (texelFetch(u_accum, ivec2(gl_FragCoord.xy), 0).a < 1.0 - TRANSMITTANCE_THRESHOLD) {
        discard;
    }
}

#else  // SCREEN_TILES

out float f_saturated;

void main() {
    ivec2 size = textureSize(u_accum, 0);
    ivec2 base = ivec2(gl_FragCoord.xy) * OCCLUSION_TILE;
    ivec2 end = min(base + OCCLUSION_TILE, size);
    float lowest = 1.0;
    for (int y = base.y; y < end.y; ++y) {
        for (int x = base.x; x < end.x; ++x) {
            lowest = min(lowest, texelFetch(u_accum, ivec2(x, y), 0).a);
        }
    }
    f_saturated = lowest >= 1.0 - TRANSMITTANCE_THRESHOLD ? 1.0 : 0.0;
}

#endif
#endif
