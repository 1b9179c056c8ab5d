#version 330 core
// Coloured 3D line segments over the splats: the desktop app's camera path and camera frustums
// (splatreel.viewer.overlay). Projected with the same pinhole convention as the splats (OpenCV camera axes, pixel
// intrinsics, y down), so a line through a Gaussian's mean passes through its splat's centre. Clip space is
// (2 (fx x + cx z) / W - z, z - 2 (fy y + cy z) / H, z - 2 NEAR, z): w = z, and GL's clipping against
// -w <= z_clip cuts segments exactly at the near plane z = NEAR, in front of the camera.

#define LINE_NEAR 0.01

#if defined VERTEX_SHADER

uniform mat4 u_w2c;         // world -> camera (OpenCV axes), column-major
uniform vec4 u_intrinsics;  // fx, fy, cx, cy in pixels
uniform vec2 u_size;        // image width, height in pixels

in vec3 in_position;        // world space
in vec3 in_color;

out vec3 v_color;

void main() {
    vec3 p = (u_w2c * vec4(in_position, 1.0)).xyz;
    gl_Position = vec4(2.0 * (u_intrinsics.x * p.x + u_intrinsics.z * p.z) / u_size.x - p.z,
                       p.z - 2.0 * (u_intrinsics.y * p.y + u_intrinsics.w * p.z) / u_size.y,
                       p.z - 2.0 * LINE_NEAR, p.z);
    v_color = in_color;
}

#elif defined FRAGMENT_SHADER

in vec3 v_color;
out vec4 f_color;

void main() {
    f_color = vec4(v_color, 1.0);
}

#endif
