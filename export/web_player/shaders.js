// The web player's GLSL ES 3.00 shaders (splatreel export web): the vertex shader evaluates each Gaussian at
// time t as the desktop pre-pass does (shaders/splat_preprocess.glsl) and uses its EWA footprint and its skinning,
// inserted below at export time (shaders/splat_footprint.glsl, splat_skin.glsl); the fragment shader draws the
// splat as shaders/splat_draw.glsl does.
// Loaded before player.js, which compiles them.
const SPLATREEL_VERTEX = `
layout(location = 0) in uint a_index;
uniform highp sampler2D u_geom;
uniform highp sampler2D u_sh;
uniform mat3 u_rot;        // world -> camera rotation (OpenCV axes)
uniform vec3 u_trans;      // world -> camera translation
uniform vec3 u_campos;     // camera centre
uniform vec4 u_intr;       // fx fy cx cy (pixels)
uniform vec2 u_size;       // image width, height (pixels)
uniform float u_time;
uniform float u_duration;  // T, the period scale of the colour's time terms
uniform int u_count;       // Gaussians per key
uniform int u_key0, u_key1;
uniform float u_w;         // keyframed: weight of key 1
#ifdef SH_U8
uniform vec4 u_sh_lo[SH_TEXELS];
uniform vec4 u_sh_step[SH_TEXELS];
#endif
out vec2 v_uv;
flat out vec4 v_color;
flat out vec4 v_rect;
flat out float v_radius2;

const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float TWO_PI = 6.283185307179586;
#define SH_BASES ((SH_DEGREE + 1) * (SH_DEGREE + 1))

vec4 geom(int row, int k) {  // texel k of a row of GEOM_TEXELS (4, or 5 with accelerations, 6 skinned)
  int i = row * GEOM_TEXELS + k;
  return texelFetch(u_geom, ivec2(i % GEOM_W, i / GEOM_W), 0);
}

vec4 sh_texel(int row, int k) {
  int i = row * SH_TEXELS + k;
  vec4 v = texelFetch(u_sh, ivec2(i % SH_W, i / SH_W), 0);
#ifdef SH_U8
  v = u_sh_lo[k] + u_sh_step[k] * floor(v * 255.0 + 0.5);
#endif
  return v;
}

mat3 rotmat(vec4 q) {  // (w, x, y, z), normalised here
  q = q / max(length(q), 1e-12);
  float w = q.x, x = q.y, y = q.z, z = q.w;
  return mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),   // column 0
              2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),   // column 1
              2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));  // column 2
}

#ifdef KEYFRAMED
vec4 slerp(vec4 a, vec4 b, float w) {  // along the shorter arc, nlerp when nearly equal
  a = a / max(length(a), 1e-12);
  b = b / max(length(b), 1e-12);
  float d = dot(a, b);
  if (d < 0.0) { b = -b; d = -d; }
  float theta = acos(min(d, 1.0));
  float s = sin(theta);
  vec4 q = s < 1e-6 ? (1.0 - w) * a + w * b : (sin((1.0 - w) * theta) * a + sin(w * theta) * b) / s;
  return q / max(length(q), 1e-12);
}
#endif

vec3 sh_color(int row0, int row1, float w, vec3 dir, float tau) {
  float c[SH_TEXELS * 4];
  for (int k = 0; k < SH_TEXELS; ++k) {
    vec4 v = sh_texel(row0, k);
#ifdef KEYFRAMED
    v = mix(v, sh_texel(row1, k), w);
#endif
    c[4 * k] = v.x; c[4 * k + 1] = v.y; c[4 * k + 2] = v.z; c[4 * k + 3] = v.w;
  }
  vec3 coef[SH_BASES];
  for (int j = 0; j < SH_BASES; ++j) coef[j] = vec3(c[3 * j], c[3 * j + 1], c[3 * j + 2]);
#if SH_DEGREE_T > 0
  for (int n = 1; n <= SH_DEGREE_T; ++n) {
    float cw = cos(TWO_PI * float(n) * tau / u_duration);
    for (int j = 0; j < SH_BASES; ++j) {
      int k = 3 * (n * SH_BASES + j);
      coef[j] += cw * vec3(c[k], c[k + 1], c[k + 2]);
    }
  }
#endif
  vec3 result = SH_C0 * coef[0];
#if SH_DEGREE >= 1
  vec3 d = normalize(dir);
  float x = d.x, y = d.y, z = d.z;
  result += -SH_C1 * y * coef[1] + SH_C1 * z * coef[2] - SH_C1 * x * coef[3];
#if SH_DEGREE >= 2
  float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  result += 1.0925484305920792 * xy * coef[4] - 1.0925484305920792 * yz * coef[5]
          + 0.31539156525252005 * (2.0 * zz - xx - yy) * coef[6] - 1.0925484305920792 * xz * coef[7]
          + 0.5462742152960396 * (xx - yy) * coef[8];
#if SH_DEGREE >= 3
  result += -0.5900435899266435 * y * (3.0 * xx - yy) * coef[9] + 2.890611442640554 * xy * z * coef[10]
          - 0.4570457994644658 * y * (4.0 * zz - xx - yy) * coef[11]
          + 0.3731763325901154 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * coef[12]
          - 0.4570457994644658 * x * (4.0 * zz - xx - yy) * coef[13] + 1.445305721320277 * z * (xx - yy) * coef[14]
          - 0.5900435899266435 * x * (xx - 3.0 * yy) * coef[15];
#endif
#endif
#endif
  return max(result + 0.5, vec3(0.0));
}

/*SPLAT_FOOTPRINT*/

#ifdef SKINNED
/*SPLAT_SKIN*/
#endif

void cull() {
  gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside the clip volume
  v_uv = vec2(0.0);
  v_color = vec4(0.0);
  v_rect = vec4(0.0);
  v_radius2 = 0.0;
}

void main() {
  int i = int(a_index);
#ifdef KEYFRAMED
  int row0 = u_key0 * u_count + i, row1 = u_key1 * u_count + i;
  vec4 g0 = geom(row0, 0), g1 = geom(row1, 0);
  vec3 mean = mix(g0.xyz, g1.xyz, u_w);
  float opacity = mix(g0.w, g1.w, u_w);
  if (!(opacity > 0.0)) { cull(); return; }
  vec4 quat = u_w == 0.0 ? geom(row0, 2) : slerp(geom(row0, 2), geom(row1, 2), u_w);
  vec3 scale = mix(geom(row0, 3).xyz, geom(row1, 3).xyz, u_w);
  float tau = 0.0;
#else
  int row0 = i, row1 = i;
  vec4 m = geom(i, 0), motion = geom(i, 1), shape = geom(i, 3);
  float dt = u_time - m.w;
  float marginal = exp(-dt * dt * motion.w);
  if (!(marginal > TEMPORAL_CULL)) { cull(); return; }
  float opacity = shape.w * marginal;
#if defined(SKINNED)  // splatreel.skinned: the canonical mean (not moved by v) carried by the nodes at t
  mat3 blend;
  vec3 mean = skin_carry(m.xyz, geom(i, 4), geom(i, 5), 0, blend);
#elif defined(ACCELERATED)
  vec3 mean = m.xyz + (motion.xyz + 0.5 * geom(i, 4).xyz * dt) * dt;  // splatreel.model: mu + v dt + a dt^2 / 2
#else
  vec3 mean = m.xyz + motion.xyz * dt;
#endif
  vec4 quat = geom(i, 2);
  vec3 scale = shape.xyz;
  float tau = -dt;
#endif
  if (!(opacity >= ALPHA_THRESHOLD)) { cull(); return; }

  // EWA projection: splat_footprint(), the desktop pre-pass's own (shaders/splat_footprint.glsl, inserted above)
  vec3 p = u_rot * mean + u_trans;
  if (!(p.z > NEAR_PLANE)) { cull(); return; }
  mat3 ms = rotmat(quat) * mat3(scale.x, 0.0, 0.0, 0.0, scale.y, 0.0, 0.0, 0.0, scale.z);
  mat3 cov = ms * transpose(ms);
#ifdef SKINNED
  cov = blend * cov * transpose(blend);
#endif
  Footprint f;
  if (!splat_footprint(p, u_rot, cov, opacity, u_intr, u_size, f)) { cull(); return; }
  float radius = f.radius;
  vec2 centre = f.centre, axis1 = f.axis1, axis2 = f.axis2;
  vec2 half_box = min(vec2(f.box), radius * f.spread + 1.0);
  vec2 lo = centre - half_box, hi = centre + half_box;
  if (footprint_outside(f, half_box, u_size)) { cull(); return; }

  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
  vec2 uv = corner * max(radius, 1e-6);
  vec2 px = centre + axis1 * uv.x + axis2 * uv.y;
  gl_Position = vec4(2.0 * px.x / u_size.x - 1.0, 1.0 - 2.0 * px.y / u_size.y, 0.0, 1.0);
  v_uv = uv;
  v_color = vec4(sh_color(row0, row1, u_w, mean - u_campos, tau), opacity);
  v_radius2 = radius * radius;
  v_rect = vec4(floor(lo / float(TILE_SIZE)), ceil(hi / float(TILE_SIZE))) * float(TILE_SIZE);
}
`;

const SPLATREEL_FRAGMENT = `
precision highp float;
uniform float u_height;
in vec2 v_uv;
flat in vec4 v_color;
flat in vec4 v_rect;
flat in float v_radius2;
out vec4 f_color;
/*SPLAT_ALPHA*/
void main() {
  vec2 pixel = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y);  // pixel centre, y down
  float alpha = splat_alpha(v_color.a, dot(v_uv, v_uv), v_radius2, pixel, v_rect);
  if (alpha == 0.0) discard;  // adds nothing; a GPU skips the blend
  f_color = vec4(v_color.rgb * alpha, alpha);
}
`;
