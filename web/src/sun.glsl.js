// Shaders of the sun's shadows (sun.js, docs/sun.md): the coarse depth map's reduction, the
// visibility pass that filters each depth-map texel to the penumbra of the sun's disc
// (percentage-closer soft shadows), the depth pass's normals, and sunShadowChunk, the GLSL
// every surface material includes to read the maps. Strings and the constants they are built
// with; the render targets and passes that run them are sun.js's.

export const SUN_ANGULAR_RADIUS_DEG = 0.2666;
const TAN_SUN = Math.tan(SUN_ANGULAR_RADIUS_DEG * Math.PI / 180);
// The maps' size in texels: 2048 by default, 1024 on a phone (sun.js mapSizeFor, docs/web.md
// "GPU memory"). Shaders read it from the define SUN_MAP_SIZE (an int), set by sun.js.
export const MAP_SIZE = 2048;
export const PHONE_MAP_SIZE = 1024;
// The coarse map: per CELL x CELL block of the depth map, the least and greatest depth over
// the block and CELL texels around it, so one read answers "no caster near" (lit) or "casters
// everywhere near" (umbra) for any search disc of up to CELL texels.
export const CELL = 16;
export const COARSE = MAP_SIZE / CELL;

/** Vogel's spiral: `count` evenly spread points on the unit disc, as a GLSL vec2 array. */
function spiral(name, count) {
  const points = Array.from({ length: count }, (_, i) => {
    const r = Math.sqrt((i + 0.5) / count);
    const a = i * 2.39996323;
    return `vec2(${(r * Math.cos(a)).toFixed(6)}, ${(r * Math.sin(a)).toFixed(6)})`;
  });
  return `const vec2 ${name}[${count}] = vec2[](${points.join(', ')});`;
}

// The filter's samples where its result is kept in the visibility maps (the ground, and the
// surfaces the sun meets first), and where a frame filters (inside a shadow's edge on a
// surface other than the ground: a few pixels, in a penumbra a few centimetres wide).
const BLOCKER_SAMPLES = 12;
const FILTER_SAMPLES = 32;
const QUICK_BLOCKER_SAMPLES = 8;
const QUICK_FILTER_SAMPLES = 16;

// 16-bit depths in two 8-bit channels (RGBA8 renders everywhere; float targets do not).
const PACK16 = /* glsl */ `
vec2 pack16(float units) { return vec2(floor(units / 256.0), mod(units, 256.0)) / 255.0; }
float unpack16(vec2 p) { return (p.x * 65280.0 + p.y * 255.0) / 65535.0; }
`;

/** Reduction of the depth map to its coarse map, along x (pass 0) then y (pass 1). */
export function coarseFragment(pass, mapSize = MAP_SIZE) {
  const read = pass === 0
    ? 'float d = texelFetch(source, ivec2(x, y), 0).r; lo = min(lo, d); hi = max(hi, d);'
    : 'vec4 t = texelFetch(source, ivec2(x, y), 0); lo = min(lo, unpack16(t.rg)); hi = max(hi, unpack16(t.ba));';
  const loop = pass === 0
    ? `int y = int(gl_FragCoord.y); int c = int(gl_FragCoord.x);
  for (int x = max(0, (c - 1) * ${CELL}); x < min(SUN_MAP_SIZE, (c + 2) * ${CELL}); x++) { ${read} }`
    : `int x = int(gl_FragCoord.x); int c = int(gl_FragCoord.y);
  for (int y = max(0, (c - 1) * ${CELL}); y < min(SUN_MAP_SIZE, (c + 2) * ${CELL}); y++) { ${read} }`;
  return /* glsl */ `
precision highp float;
precision highp int;
#define SUN_MAP_SIZE ${mapSize}
uniform highp sampler2D source;
out vec4 outColor;
${PACK16}
void main() {
  float lo = 1.0;
  float hi = 0.0;
  ${loop}
  // rounded outward: the bounds stay bounds
  outColor = vec4(pack16(floor(lo * 65535.0)), pack16(ceil(hi * 65535.0)));
}
`;
}

/** The visibility maps' passes: per texel of a depth map, with the same filter as
 * sunVisibilityIn, `part` 'surface': the sun's visibility of the surface the texel sees (R)
 * and the texel's depth (0..1 of near..far, 16 bits in B and A) into an RGBA8 target, a
 * surface needs one read of it (its point from the depth, its normal from the colour the depth
 * pass wrote, NORMAL_FRAGMENT); 'ground': the visibility of the flat ground under the texel
 * into an R8 target (a quarter of the bytes to read per ground pixel, mipmapped). */
export function visibilityFragment(part, mapSize = MAP_SIZE) {
  return /* glsl */ `
precision highp float;
precision highp int;
#define SUN 1
#define SUN_MAP_SIZE ${mapSize}
#define PART_GROUND ${part === 'ground' ? 1 : 0}
#define texture2D texture
${sunShadowChunk}
uniform sampler2D depthMap;
uniform sampler2D normalMap;
uniform sampler2D coarseMap;
uniform mat4 worldToMap;
uniform vec4 mapInfo;
// World points of the texel at uv (0..1): on the near plane nearOrigin + uv.x axisU +
// uv.y axisV, plus depth01 axisDepth; on the ground groundOrigin + uv.x groundAxisU + ...
uniform vec3 nearOrigin;
uniform vec3 axisU;
uniform vec3 axisV;
uniform vec3 axisDepth;
uniform vec3 groundOrigin;
uniform vec3 groundAxisU;
uniform vec3 groundAxisV;
out vec4 outColor;
void main() {
  vec2 uv = gl_FragCoord.xy / float(SUN_MAP_SIZE);
  ivec2 t = ivec2(gl_FragCoord.xy);
#if PART_GROUND == 1
  vec3 g = groundOrigin + uv.x * groundAxisU + uv.y * groundAxisV;
  outColor = vec4(sunVisibilityIn(depthMap, coarseMap, worldToMap, mapInfo, g, vec3(0.0, 1.0, 0.0)), 0.0, 0.0, 1.0);
#else
  float depth01 = texelFetch(depthMap, t, 0).r;
  vec3 n = texelFetch(normalMap, t, 0).xyz * 2.0 - 1.0;
  vec3 p = nearOrigin + uv.x * axisU + uv.y * axisV + depth01 * axisDepth;
  float surface = 1.0;
  for (int k = 0; k < (depth01 < 1.0 ? 1 : 0); k++) {  // a texel that sees a surface
    surface = sunVisibilityIn(depthMap, coarseMap, worldToMap, mapInfo, p, normalize(n));
  }
  outColor = vec4(surface, 0.0, pack16(floor(depth01 * 65535.0 + 0.5)));
#endif
}
`;
}

// The depth pass writes the world normal of the face toward the sun (as colour, 0..1).
export const NORMAL_VERTEX = /* glsl */ `
varying vec3 vNormalW;
void main() {
  vNormalW = normalize(mat3(modelMatrix) * normal);
  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
}
`;
export const NORMAL_FRAGMENT = /* glsl */ `
uniform vec3 toSun;
varying vec3 vNormalW;
void main() {
  vec3 n = normalize(vNormalW);
  if (dot(n, toSun) < 0.0) n = -n;
  gl_FragColor = vec4(n * 0.5 + 0.5, 1.0);
}
`;

/**
 * GLSL of the penumbra filter, `float name(depth map, coarse map, M, info, world point, normal)`:
 * the fraction of the sun's disc seen past one caster set from a world point with normal n,
 * with `blockers` samples in the blocker search and `filters` in the disc filter.
 * One exit and loops whose counts are 0 where they are not needed: a software GPU
 * (SwiftShader) runs the code under a branch not taken with its lanes masked, but leaves a
 * loop as soon as no lane needs another turn.
 */
function penumbraFilter(name, blockers, filters) {
  return /* glsl */ `
${spiral(`${name}_BLOCKERS`, blockers)}
${spiral(`${name}_FILTERS`, filters)}
float ${name}(sampler2D map, sampler2D coarse, mat4 M, vec4 info, vec3 position, vec3 n) {
#if SUN == 0
  return 1.0;
#else
  float texel = info.x;
  vec4 clip = M * vec4(position + n * (1.5 * texel), 1.0);
  vec3 q = clip.xyz * 0.5 + 0.5;
  float depth = info.y + q.z * info.z;   // metres from the sun camera
  float bias = 1.5 * texel;
  float toUv = 1.0 / (texel * float(SUN_MAP_SIZE));
  // A blocker lies between the near plane (the casters' nearest point) and the receiver.
  float searchM = max((depth - info.y) * TAN_SUN, 1.5 * texel);
  bool inMap = info.w > 0.5 && q.x > 0.0 && q.y > 0.0 && q.x < 1.0 && q.y < 1.0 && q.z < 1.0;
  float visible = 1.0;
  int blockerCount = inMap ? ${blockers} : 0;
  if (inMap && searchM <= ${CELL}.0 * texel) {
    // One read of the coarse map settles most pixels: no caster near, or casters all around.
    vec4 bounds = texelFetch(coarse, ivec2(q.xy * float(SUN_MAP_SIZE / ${CELL})), 0);
    bool clear = info.y + unpack16(bounds.rg) * info.z >= depth - bias;
    bool covered = info.y + unpack16(bounds.ba) * info.z < depth - bias;
    if (clear || covered) blockerCount = 0;
    if (covered) visible = 0.0;
  }
  // Interleaved gradient noise turns the spirals from pixel to pixel (no banding).
  float turn = 6.2831853 * fract(52.9829189 * fract(dot(gl_FragCoord.xy, vec2(0.06711056, 0.00583715))));
  mat2 rotate = mat2(cos(turn), sin(turn), -sin(turn), cos(turn));
  // 1. Blockers: any caster nearer than the receiver within the largest penumbra possible.
  float searchUv = searchM * toUv;
  float blockers = 0.0;
  float blockerDepth = 0.0;
  for (int i = 0; i < blockerCount; i++) {
    float z = info.y + texture2D(map, q.xy + rotate * ${name}_BLOCKERS[i] * searchUv).r * info.z;
    if (z < depth - bias) { blockers += 1.0; blockerDepth += z; }
  }
  // All blocked: umbra; none: lit; else the penumbra's filter below.
  if (blockerCount > 0 && blockers == ${blockers}.0) visible = 0.0;
  int filterCount = blockers > 0.0 && blockers < ${blockers}.0 ? ${filters} : 0;
  // 2. The disc's footprint at the blockers' mean distance: each sample is one direction
  //    within the sun's disc, blocked or not.
  float radiusUv = max((depth - blockerDepth / max(blockers, 1.0)) * TAN_SUN, texel) * toUv;
  float lit = 0.0;
  for (int i = 0; i < filterCount; i++) {
    float z = info.y + texture2D(map, q.xy + rotate * ${name}_FILTERS[i] * radiusUv).r * info.z;
    lit += z < depth - bias ? 0.0 : 1.0;
  }
  if (filterCount > 0) visible = lit / ${filters}.0;
  return visible;
#endif
}
`;
}

/**
 * GLSL of the sun term, shared by every material that receives the sun. Uniforms:
 * sunIrradiance (RGB normal irradiance, W/m^2), sunDirection (unit, toward the sun), and per
 * caster set X in {A (all), R (real)}: sunMapX (depth), sunMatrixX (world -> the sun camera's
 * clip space), sunInfoX = (metres per texel, near m, far - near m, 1 when the map holds
 * casters), sunCoarseX (its coarse map), sunVisibilityX (its visibility map). Compiled with
 * SUN 0 (materials' define) it draws no sun and costs nothing. Per frame a surface reads its
 * visibility map once (sunVisibilityOnGround, sunVisibilityOnSurface); sunVisibilityIn, the
 * full filter, runs in the visibility pass and where a view pass runs once per sun move.
 */
export const sunShadowChunk = /* glsl */ `
#ifndef SUN_MAP_SIZE
#define SUN_MAP_SIZE ${MAP_SIZE}
#endif
uniform vec3 sunIrradiance;
uniform vec3 sunDirection;
uniform sampler2D sunMapA;
uniform sampler2D sunMapR;
uniform mat4 sunMatrixA;
uniform mat4 sunMatrixR;
uniform vec4 sunInfoA;
uniform vec4 sunInfoR;
uniform sampler2D sunCoarseA;
uniform sampler2D sunCoarseR;
uniform sampler2D sunVisibilityA;
uniform sampler2D sunVisibilityR;
uniform sampler2D sunGroundA;
uniform sampler2D sunGroundR;
const float TAN_SUN = ${TAN_SUN.toFixed(9)};
${PACK16}

${penumbraFilter('sunVisibilityIn', BLOCKER_SAMPLES, FILTER_SAMPLES)}
${penumbraFilter('sunVisibilityQuick', QUICK_BLOCKER_SAMPLES, QUICK_FILTER_SAMPLES)}

// Fraction of the sun's disc seen past one caster set from a point of the flat ground: the
// ground visibility map (the filter run once per texel when the maps were rendered), one
// bilinear read at full resolution: the value at the pixel's centre ray (the kiosk's passes,
// as the bake's views are).
float sunVisibilityOnGround(sampler2D visibility, mat4 M, vec4 info, vec3 position) {
#if SUN == 0
  return 1.0;
#else
  vec2 q = (M * vec4(position, 1.0)).xy * 0.5 + 0.5;
  bool inMap = info.w > 0.5 && q.x > 0.0 && q.y > 0.0 && q.x < 1.0 && q.y < 1.0;
  return inMap ? textureLod(visibility, q, 0.0).r : 1.0;
#endif
}

// The same at the point q (0..1) of the map, prefiltered to the pixel's footprint (its
// mipmap level): a frame's ground, where a distant pixel covers many texels.
float sunVisibilityOnGroundPrefiltered(sampler2D visibility, vec4 info, vec2 q) {
#if SUN == 0
  return 1.0;
#else
  bool inMap = info.w > 0.5 && q.x > 0.0 && q.y > 0.0 && q.x < 1.0 && q.y < 1.0;
  // Read outside any condition that varies between pixels: a mipmap level needs the
  // neighbouring pixels' coordinates.
  float visible = texture2D(visibility, q).r;
  return inMap ? visible : 1.0;
#endif
}

// The same from a point of any surface with normal n: where it is the surface its texel of
// the depth map sees (the first the sun meets: lit, or a penumbra's outer half) the
// visibility map's R, read once; behind it (an umbra, a penumbra's inner half) or in front of
// it (a surface that casts no shadow, e.g. a hull plane) the filter. Facing away from the
// sun: 1 (its cosine is 0).
float sunVisibilityOnSurface(sampler2D map, sampler2D coarse, sampler2D visibility, mat4 M, vec4 info, vec3 position, vec3 n) {
#if SUN == 0
  return 1.0;
#else
  float cosSun = dot(n, sunDirection);
  float visible = 1.0;
  // Facing away from the sun its cosine is 0: nothing to read (a loop run 0 times costs
  // nothing on a software GPU, a branch not taken does).
  for (int face = 0; face < (cosSun > 0.0 ? 1 : 0); face++) {
    float texel = info.x;
    vec3 q = (M * vec4(position + n * (1.5 * texel), 1.0)).xyz * 0.5 + 0.5;
    bool inMap = info.w > 0.5 && q.x > 0.0 && q.y > 0.0 && q.x < 1.0 && q.y < 1.0 && q.z < 1.0;
    ivec2 t = ivec2(clamp(q.xy * float(SUN_MAP_SIZE), vec2(0.0), vec2(float(SUN_MAP_SIZE - 1))));
    // Metres from the surface the texel sees to this point. On that surface, moved 1.5 texels
    // along its normal, the point is 1.5 texels / cos nearer the sun than the surface's depth
    // there, within its slope (tan) times the 0.71 texel from a texel's centre to its corner.
    vec4 v = texelFetch(visibility, t, 0);
    float behind = (q.z - unpack16(v.ba)) * info.z;
    float c = max(cosSun, 0.125);
    float slope = sqrt(1.0 - c * c) / c;
    bool seen = abs(behind + 1.5 * texel / c) < texel * (1.0 + 0.75 * slope);
    visible = inMap ? v.r : 1.0;
    bool refilter = inMap && !seen;
    // Behind casters all around (the coarse map's greatest depth nearer than the point): umbra.
    for (int k = 0; k < (refilter ? 1 : 0); k++) {
      float deepest = unpack16(texelFetch(coarse, ivec2(q.xy * float(SUN_MAP_SIZE / ${CELL})), 0).ba);
      if ((q.z - deepest) * info.z > 1.5 * texel) { visible = 0.0; refilter = false; }
    }
    for (int k = 0; k < (refilter ? 1 : 0); k++) visible = sunVisibilityQuick(map, coarse, M, info, position, n);
  }
  return visible;
#endif
}

// The sun's cosine-weighted normal irradiance on a surface (W/m^2, RGB), unshadowed.
vec3 sunOnSurface(vec3 n) {
#if SUN == 0
  return vec3(0.0);
#else
  return sunIrradiance * max(dot(n, sunDirection), 0.0);
#endif
}
`;
