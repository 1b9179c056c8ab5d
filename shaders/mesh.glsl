#version 330 core
// Lit, vertex-coloured triangle meshes for the procedural samples (splatreel.samples.render).
//
// Vertices arrive in world space (the samples are evaluated at each time on the CPU, so there is no model
// matrix). Shading is Lambert + ambient with a light fixed in WORLD space, so a surface point looks the same from
// every camera (view-independent, like SH degree 0): colour = albedo * (u_ambient + u_diffuse * max(n.l, 0)).
// The same formula runs on the CPU in `splatreel.samples.render.shade` (used to colour Gaussians built from a
// sample); keep the two in step.

#if defined VERTEX_SHADER

uniform mat4 u_view;        // world -> OpenGL camera (inverse of Camera.to_opengl_c2w())
uniform mat4 u_proj;        // Camera.opengl_projection()

in vec3 in_position;        // world space
in vec3 in_normal;          // world space, unit, outward
in vec3 in_color;           // albedo in [0, 1]

out vec3 v_normal;
out vec3 v_color;

void main() {
    v_normal = in_normal;
    v_color = in_color;
    gl_Position = u_proj * u_view * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform vec3 u_light_dir;   // unit vector towards the light, world space
uniform float u_ambient;
uniform float u_diffuse;

in vec3 v_normal;
in vec3 v_color;

out vec4 f_color;

void main() {
    vec3 n = normalize(v_normal);
    // Two-sided: the back of an open surface is lit like its front (closed samples never show back faces).
    if (!gl_FrontFacing) n = -n;
    float lambert = max(dot(n, u_light_dir), 0.0);
    // Alpha 1 on a (0,0,0,0) clear: the multisample resolve and box filter then give premultiplied colour
    // and coverage, from which straight alpha is recovered on the CPU.
    f_color = vec4(v_color * (u_ambient + u_diffuse * lambert), 1.0);
}

#endif
