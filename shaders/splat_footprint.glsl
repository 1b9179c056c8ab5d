// The screen footprint of one 3D Gaussian: the one copy of the trainer's EWA projection in GLSL, included by the
// desktop pre-pass (splat_preprocess.glsl, through splatreel.gl's #include) and inserted into the web player's
// vertex shader when it is exported (export/web.py). No #version: it is a part of those programs.
//
// EWA splatting (Zwicker et al. 2001) as the reference 3DGS rasterizer does it (graphdeco-inria
// diff-gaussian-rasterization, cuda_rasterizer/forward.cu computeCov2D): OpenCV camera, the Jacobian taken at x/z,
// y/z clamped to the image plus (FRUSTUM_CLAMP - 1) tan_fov on each side, the 2D covariance J R Sigma R^T J^T + EPS2D I,
// its principal axes, the alpha radius out to ALPHA_THRESHOLD and the reference's square box of radius
// ceil(RADIUS_SIGMAS sqrt(lambda_max)) (EIGEN_FLOOR under the discriminant).

struct Footprint {
    vec2 centre;    // pixel position of the mean
    vec2 axis1;     // principal axes: unit eigenvectors times the std-devs (pixels)
    vec2 axis2;
    float major;    // the larger eigenvalue (pixels^2)
    float radius;   // the alpha >= ALPHA_THRESHOLD radius, in std-devs
    vec2 spread;    // std-devs along x and y (pixels)
    float box;      // the reference's square box half-size, whole pixels
};

// p: the mean in camera coordinates (z > near, checked by the caller); rot: world -> camera rotation; cov:
// the world covariance; intr: fx, fy, cx, cy; size: the image in pixels. False for a degenerate footprint.
bool splat_footprint(vec3 p, mat3 rot, mat3 cov, float opacity, vec4 intr, vec2 size, out Footprint f) {
    float fx = intr.x, fy = intr.y, cx = intr.z, cy = intr.w;
    float slack_x = (FRUSTUM_CLAMP - 1.0) * 0.5 * size.x / fx;
    float slack_y = (FRUSTUM_CLAMP - 1.0) * 0.5 * size.y / fy;
    float tx = p.z * clamp(p.x / p.z, -(cx / fx + slack_x), (size.x - cx) / fx + slack_x);
    float ty = p.z * clamp(p.y / p.z, -(cy / fy + slack_y), (size.y - cy) / fy + slack_y);
    float iz = 1.0 / p.z;
    vec3 t0 = vec3(fx * iz, 0.0, -fx * tx * iz * iz) * rot;  // rows of J R
    vec3 t1 = vec3(0.0, fy * iz, -fy * ty * iz * iz) * rot;
    vec3 ct0 = cov * t0;
    float a = dot(t0, ct0) + EPS2D;
    float b = dot(t1, ct0);
    float c = dot(t1, cov * t1) + EPS2D;
    float det = a * c - b * b;
    if (!(det > 0.0)) return false;
    // principal axes of the 2D covariance: lambda1 >= lambda2 > 0
    float mid = 0.5 * (a + c);
    float disc = sqrt(max(mid * mid - det, 0.0));
    float l1 = mid + disc;
    float l2 = det / l1;
    vec2 e1 = vec2(b, l1 - a);
    float len1 = length(e1);
    e1 = len1 > 1e-12 * l1 ? e1 / len1 : (a >= c ? vec2(1.0, 0.0) : vec2(0.0, 1.0));
    f.centre = vec2(fx * p.x * iz + cx, fy * p.y * iz + cy);
    f.axis1 = e1 * sqrt(l1);
    f.axis2 = vec2(-e1.y, e1.x) * sqrt(l2);
    f.major = l1;
    // alpha = o exp(-r^2 / 2) >= ALPHA_THRESHOLD exactly inside r^2 = 2 ln(o / ALPHA_THRESHOLD)
    f.radius = sqrt(2.0 * log(opacity / ALPHA_THRESHOLD));
    f.spread = sqrt(vec2(a, c));
    f.box = ceil(RADIUS_SIGMAS * sqrt(mid + sqrt(max(EIGEN_FLOOR, mid * mid - det))));
    return true;
}

// Whether the footprint's box (and its half_box around the centre) misses an image of size pixels.
bool footprint_outside(Footprint f, vec2 half_box, vec2 size) {
    vec2 lo = f.centre - half_box, hi = f.centre + half_box;
    return any(lessThanEqual(f.centre + f.box, vec2(0.0))) || any(greaterThanEqual(f.centre - f.box, size))
        || any(lessThan(hi, vec2(0.0))) || any(greaterThan(lo, size));
}
