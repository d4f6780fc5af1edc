// Shaders of the relight pass (Kakuta Fig. 6: the weighted sum of basis images on the GPU).
// One fragment per texel of the atlas (or view): gl_FragCoord row y is image row y (top
// first), exactly the texel texelFetch reads, so no filtering touches the basis values.

export const relightVertex = /* glsl */ `
in vec3 position;
void main() { gl_Position = vec4(position.xy, 0.0, 1.0); }
`;

/**
 * The fragment shader of one compact stack (docs/compact-assets.md):
 * E(x) = g(x) (sum_j c[coef_j] (tex_j(x) scale_j + offset_j) + sum_i r_i sum_lv (light_i_lv(x) scale + offset))
 * with the products and offsets folded into layerWeight, slotWeight and constant (lightmath.js).
 * The last `etc1sLayers` of the `layers` are in a second array, etc1sTex (ETC1S; builds from
 * 2026-11-24), the others in baseTex.
 */
export function relightFragment({ layers, etc1sLayers = 0, slots, gain, encodeRGBE }) {
  const head = layers - etc1sLayers;
  const slotUniforms = Array.from({ length: slots }, (_, s) => `uniform sampler2D slot${s};`).join('\n');
  const slotSum = Array.from({ length: slots },
    (_, s) => `  e += texelFetch(slot${s}, p, 0).rgb * slotWeight[${s}];`).join('\n');
  return /* glsl */ `
precision highp float;
precision highp int;
precision highp sampler2DArray;
uniform sampler2DArray baseTex;
${etc1sLayers ? 'uniform sampler2DArray etc1sTex;' : ''}
uniform vec3 layerWeight[${layers}];
uniform vec3 constantTerm;
${slots ? `uniform vec3 slotWeight[${slots}];\n${slotUniforms}` : ''}
${gain ? 'uniform sampler2DArray gainTex;\nuniform vec3 gainScale[2];\nuniform vec3 gainOffset[2];' : ''}
out vec4 outColor;
${encodeRGBE ? RGBE_ENCODE : ''}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 e = constantTerm;
  for (int j = 0; j < ${head}; j++) e += texelFetch(baseTex, ivec3(p, j), 0).rgb * layerWeight[j];
${etc1sLayers ? `  for (int j = 0; j < ${etc1sLayers}; j++) e += texelFetch(etc1sTex, ivec3(p, j), 0).rgb * layerWeight[${head} + j];` : ''}
${slotSum}
${gain ? `  vec3 g = texelFetch(gainTex, ivec3(p, 0), 0).rgb * gainScale[0] + gainOffset[0]
         + texelFetch(gainTex, ivec3(p, 1), 0).rgb * gainScale[1] + gainOffset[1];
  e *= g;` : ''}
  outColor = ${encodeRGBE ? 'encodeRGBE(e)' : 'vec4(e, 1.0)'};
}
`;
}

// Fallback for GPUs that cannot render to half-float targets: a signed shared exponent in an
// RGBA8 target (docs/web.md). rgb hold |v| / 2^e (8 bits each), alpha holds e + 16 (5 bits,
// e in -16..15: 1.5e-5 to 32768) plus a sign bit per channel (bits 5, 6, 7 for r, g, b), so
// negative values (light bounced off a virtual object, compact data's noise near zero) are kept.
// Error: at most half a step of the mantissa, 1/255 of the pixel's largest magnitude.
export const RGBE_ENCODE = /* glsl */ `
vec4 encodeRGBE(vec3 v) {
  vec3 a = abs(v);
  float m = max(max(a.r, a.g), a.b);
  if (m < 1e-30) return vec4(0.0);
  float e = clamp(ceil(log2(m)), -16.0, 15.0);
  vec3 negative = vec3(lessThan(v, vec3(0.0)));
  float signs = negative.r + 2.0 * negative.g + 4.0 * negative.b;
  return vec4(min(a / exp2(e), vec3(1.0)), (e + 16.0 + 32.0 * signs) / 255.0);
}
`;

export const RGBE_DECODE = /* glsl */ `
vec3 decodeTarget(vec4 t) {
  float a = floor(t.a * 255.0 + 0.5);
  float signs = floor(a / 32.0);
  vec3 negative = vec3(mod(signs, 2.0), mod(floor(signs / 2.0), 2.0), floor(signs / 4.0));
  return t.rgb * (1.0 - 2.0 * negative) * exp2(a - 32.0 * signs - 16.0);
}
`;

/** The RGBE_DECODE of one RGBA8 pixel in JavaScript (read-backs): [r, g, b]. */
export function decodeRGBE(r, g, b, a) {
  const scale = 2 ** ((a & 31) - 16) / 255;
  return [r, g, b].map((c, ch) => ((a >> (5 + ch)) & 1 ? -c : c) * scale);
}

export const FLOAT_DECODE = /* glsl */ `
vec3 decodeTarget(vec4 t) { return t.rgb; }
`;

/**
 * The width of the sky's smooth partition of unity over n patches (docs/manifest.md,
 * bake.views.sky_weights): w = 0.7 sqrt(2 pi / n) rad, about a patch's angular radius. The
 * shaders take 1 / w^2 (skyInvWidth2).
 */
export const SKY_WIDTH_FACTOR = 0.7;
export function skyInvWidth2(n) {
  return 1 / (SKY_WIDTH_FACTOR * Math.sqrt(2 * Math.PI / n)) ** 2;
}

/**
 * sum_i r_i phi_i(w) / sum_i phi_i(w), phi_i = exp((w . c_i - 1) / width^2): the sky's
 * radiance toward a unit world direction w from the light vector, the one GLSL copy of
 * bake.views.sky_weights. lightTex: n x 2 texels, row 0 r_i (RGB), row 1 centroid c_i.
 */
function skyRadianceChunk(lights) {
  return /* glsl */ `
uniform sampler2D lightTex;
uniform float invWidth2;    // skyInvWidth2(n)
vec3 skyRadiance(vec3 w) {
  // Subtract the largest logit first, as the reference does, so exp never underflows to 0/0.
  float best = -1e30;
  for (int i = 0; i < ${lights}; i++) {
    best = max(best, (dot(w, texelFetch(lightTex, ivec2(i, 1), 0).rgb) - 1.0) * invWidth2);
  }
  float total = 0.0;
  vec3 sky = vec3(0.0);
  for (int i = 0; i < ${lights}; i++) {
    float phi = exp((dot(w, texelFetch(lightTex, ivec2(i, 1), 0).rgb) - 1.0) * invWidth2 - best);
    total += phi;
    sky += phi * texelFetch(lightTex, ivec2(i, 0), 0).rgb;
  }
  return sky / total;
}
`;
}

/**
 * The sky seen by a fixed view's sky pixels (mask 128), skyRadiance: evaluated once per
 * light update, not per frame.
 */
export function viewSkyFragment({ lights, encodeRGBE }) {
  return /* glsl */ `
precision highp float;
uniform sampler2D maskTex;
uniform mat3 worldFromPixel; // R K^-1: pixel (x + 0.5, y + 0.5, 1) to a world direction
uniform vec2 size;
out vec4 outColor;
${encodeRGBE ? RGBE_ENCODE : ''}
${skyRadianceChunk(lights)}
void main() {
  vec2 px = floor(gl_FragCoord.xy) + 0.5;
  float m = texture(maskTex, px / size).r;
  vec3 sky = vec3(0.0);
  if (abs(m - 128.0 / 255.0) < 0.1) sky = skyRadiance(normalize(worldFromPixel * vec3(px, 1.0)));
  outColor = ${encodeRGBE ? 'encodeRGBE(sky)' : 'vec4(sky, 1.0)'};
}
`;
}

/**
 * The sky dome of the virtual visit: an equirectangular image of the upper hemisphere
 * (pixel centre u, v in 0..1: azimuth 2 pi u clockwise from north, -Z, toward east, +X;
 * elevation pi / 2 v), skyRadiance.
 */
export function domeSkyFragment({ lights, encodeRGBE }) {
  return /* glsl */ `
precision highp float;
uniform vec2 size;
out vec4 outColor;
${encodeRGBE ? RGBE_ENCODE : ''}
${skyRadianceChunk(lights)}
void main() {
  vec2 uv = gl_FragCoord.xy / size;
  float azimuth = uv.x * 6.28318530718;          // clockwise from north (-Z) toward east (+X)
  float elevation = uv.y * 1.57079632679;
  vec3 w = vec3(sin(azimuth) * cos(elevation), sin(elevation), -cos(azimuth) * cos(elevation));
  vec3 sky = skyRadiance(w);
  outColor = ${encodeRGBE ? 'encodeRGBE(sky)' : 'vec4(sky, 1.0)'};
}
`;
}
