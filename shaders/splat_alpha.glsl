// The alpha one splat adds at one pixel: the reference rasterizer's min(MAX_ALPHA, o exp(-r2 / 2)), and nothing past
// the footprint radius or outside the Gaussian's tile rectangle. The one copy for the desktop splat_draw.glsl
// (through splatreel.gl's #include) and the web player's fragment shader (inserted when it is exported, export/web.py).
// No #version: it is a part of those programs. MAX_ALPHA is defined by the program that includes it.

float splat_alpha(float opacity, float r2, float radius2, vec2 pixel, vec4 rect) {
    bool inside = all(greaterThanEqual(pixel, rect.xy)) && all(lessThan(pixel, rect.zw));
    float alpha = min(MAX_ALPHA, opacity * exp(-0.5 * r2));
    return (r2 > radius2 || !inside) ? 0.0 : alpha;
}
