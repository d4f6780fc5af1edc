// Shaders of the surfaces drawn every frame. They only sample the relight targets
// (relight.js), so their cost does not depend on the number of lights. Output is linear
// radiance times the exposure, then three.js's tone mapping and sRGB encoding.

const common = /* glsl */ `
uniform float exposure;
`;

export const uvVertex = /* glsl */ `
varying vec2 vUv;
varying vec3 vNormalW;
void main() {
  vUv = uv;
  vNormalW = normalize(mat3(modelMatrix) * normal);
  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
}
`;

export const plainVertex = /* glsl */ `
varying vec3 vNormalW;
varying vec3 vPositionW;
void main() {
  vNormalW = normalize(mat3(modelMatrix) * normal);
  vec4 world = modelMatrix * vec4(position, 1.0);
  vPositionW = world.xyz;
  gl_Position = projectionMatrix * viewMatrix * world;
}
`;

function output(expr) {
  return /* glsl */ `
  gl_FragColor = vec4(${expr}, 1.0);
  #include <tonemapping_fragment>
  #include <colorspace_fragment>
`;
}

/**
 * A surface lit from its lightmap: albedo / pi x E (E from the lightmap target). With
 * shading off (the A/B switch) it shows albedo / pi x flatIrradiance: no shading, no shadows.
 */
export const lightmapFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D irradianceTex;
uniform vec3 albedo;
uniform vec3 flatIrradiance;
uniform float shading; // 1 shaded from the lightmap, 0 flat
varying vec2 vUv;
varying vec3 vNormalW;
void main() {
  vec3 e = mix(flatIrradiance, decodeTarget(texture2D(irradianceTex, vUv)), shading);
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/**
 * Hull-plane mode (Kakuta): the virtual object's unshadowed shading from the light vector
 * (spherical harmonics of the sky, Ramamoorthi & Hanrahan Eq. 13, from the manifest's sh9),
 * darkened by the hull planes drawn over it.
 */
export const sh9Fragment = /* glsl */ `
${common}
uniform vec3 L[9];
uniform vec3 albedo;
uniform vec3 flatIrradiance;
uniform float shading;
varying vec3 vNormalW;
varying vec3 vPositionW;
vec3 irradianceSH(vec3 n) {
  const float c1 = 0.429043, c2 = 0.511664, c3 = 0.743125, c4 = 0.886227, c5 = 0.247708;
  float x = n.x, y = n.y, z = n.z;
  return c1 * L[8] * (x * x - y * y) + c3 * L[6] * z * z + c4 * L[0] - c5 * L[6]
    + 2.0 * c1 * (L[4] * x * y + L[7] * x * z + L[5] * y * z)
    + 2.0 * c2 * (L[3] * x + L[1] * y + L[2] * z);
}
void main() {
  vec3 n = normalize(vNormalW);
  if (!gl_FrontFacing) n = -n;
  vec3 e = mix(flatIrradiance, max(irradianceSH(n), vec3(0.0)), shading);
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/**
 * A shadowing plane (Kakuta Eq. 2, 4): zero reflectance, alpha = 1 - ratio with
 * ratio = sum r I / sum r d = 1 - X / D. Blending happens on sRGB-encoded colour, so the
 * linear factor `ratio` becomes ratio^(1/2.2) there. Where ratio > 1 (light bounced off a
 * virtual object) a second, additive draw of the same plane (brighten = 1) multiplies the
 * picture by the excess (blending DstColor, One).
 */
export const shadowPlaneFragment = (decode) => /* glsl */ `
${decode}
uniform sampler2D dTex;      // D = sum r d
uniform sampler2D deltaTex;  // X = sum r (d - I)
uniform float strength;      // 1 shown, 0 hidden (the A/B switch)
uniform float brighten;      // 0: the darkening draw, 1: the brightening draw
varying vec2 vUv;
void main() {
  float D = dot(decodeTarget(texture2D(dTex, vUv)), vec3(0.2126, 0.7152, 0.0722));
  float X = dot(decodeTarget(texture2D(deltaTex, vUv)), vec3(0.2126, 0.7152, 0.0722));
  float ratio = D > 1e-6 ? 1.0 - X / D : 1.0;
  ratio = mix(1.0, clamp(ratio, 0.0, 4.0), strength);
  float encoded = pow(ratio, 1.0 / 2.2);
  if (brighten > 0.5) {
    gl_FragColor = vec4(vec3(max(encoded - 1.0, 0.0)), 1.0);
  } else {
    gl_FragColor = vec4(0.0, 0.0, 0.0, 1.0 - min(encoded, 1.0));
  }
}
`;

/**
 * A real receiving surface in the virtual visit (no camera view to blend over): the
 * synthesized real scene under the same sky, albedo / pi x I with I = D - X (D alone when
 * the virtual objects' shadows are switched off).
 */
export const receiverFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D dTex;
uniform sampler2D deltaTex;
uniform vec3 albedo;
uniform float strength;
varying vec2 vUv;
void main() {
  vec3 D = decodeTarget(texture2D(dTex, vUv));
  vec3 X = decodeTarget(texture2D(deltaTex, vUv));
  vec3 e = max(D - strength * X, vec3(0.0));
  ${output('albedo / 3.14159265 * e * exposure')}
}
`;

/** The open ground beyond the atlases: lit by the open sky, sum r_i cosine_weighted_sr_i. */
export const openGroundFragment = /* glsl */ `
${common}
uniform vec3 albedo;
uniform vec3 openIrradiance;
void main() {
  ${output('albedo / 3.14159265 * openIrradiance * exposure')}
}
`;

/** The sky dome of the virtual visit, from the relit equirectangular sky image. */
export const skyVertex = /* glsl */ `
varying vec3 vDir;
void main() {
  vDir = position;
  vec4 p = projectionMatrix * mat4(mat3(viewMatrix)) * vec4(position, 1.0);
  gl_Position = p.xyww;
}
`;

export const skyFragment = (decode) => /* glsl */ `
${common}
${decode}
uniform sampler2D skyTex;
uniform vec3 horizon;
varying vec3 vDir;
void main() {
  vec3 w = normalize(vDir);
  float elevation = asin(clamp(w.y, 0.0, 1.0));
  float azimuth = atan(w.x, -w.z);
  if (azimuth < 0.0) azimuth += 6.28318530718;
  vec3 sky = decodeTarget(texture2D(skyTex, vec2(azimuth / 6.28318530718, elevation / 1.57079632679)));
  if (w.y < 0.0) sky = horizon;
  ${output('sky * exposure')}
}
`;
