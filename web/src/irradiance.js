// What a surface's material reads per frame: each atlas's irradiance without the sun's direct
// term, the relit sky (relight.js) plus the sun's bounce (sunbounce.js), summed once when
// either changes instead of in every pixel of every frame (docs/sun.md, "One read per
// surface"). On a software GPU a texture read costs about as much as the rest of a ground
// pixel's shading, and a frame drew the ground with four reads of these targets.
//
// Per atlas (relight.js: a shadowing atlas's `I` target holds Delta = d - I):
//   a lightmap atlas (stack I)        lit     = I + B_I
//   a shadowing atlas (stacks d, I)   with    = max(D - Delta, 0) + B_I   (the real scene with
//                                                                          the virtual objects)
//                                     without = D + B_d                    (without them)
// with B the sun's bounce of the same stack (black where the build has none). The shadowing
// planes' ratio is (with + S V) / (without + S Vd), the visit's real surfaces `with + S V`, or
// `without + S Vr` with the virtual objects' shading switched off (materials.glsl.js).
import * as THREE from 'three';
import { FLOAT_DECODE, RGBE_DECODE, RGBE_ENCODE } from './relight.glsl.js';
import { FullscreenPass, makeTarget } from './passes.js';

/** out = max(a wa + b wb, 0) + c: the sum of three relight-format targets, texel by texel. */
function sumFragment(rgbe) {
  return /* glsl */ `
precision highp float;
uniform sampler2D a;
uniform sampler2D b;
uniform sampler2D c;
uniform float wa;
uniform float wb;
out vec4 outColor;
${rgbe ? RGBE_DECODE : FLOAT_DECODE}
${rgbe ? RGBE_ENCODE : ''}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 e = max(decodeTarget(texelFetch(a, p, 0)) * wa + decodeTarget(texelFetch(b, p, 0)) * wb, vec3(0.0))
    + decodeTarget(texelFetch(c, p, 0));
  outColor = ${rgbe ? 'encodeRGBE(e)' : 'vec4(e, 1.0)'};
}
`;
}

export class IrradianceTargets {
  /**
   * @param {THREE.WebGLRenderer} renderer
   * @param {import('./relight.js').Relighter} relighter its targets are the relit sky
   * @param {import('./sunbounce.js').SunBounce|null} sunBounce the sun's bounce targets
   */
  constructor(renderer, relighter, sunBounce) {
    this.renderer = renderer;
    // Read as zero in either format (RGBE: exponent byte 0).
    const black = new THREE.DataTexture(new Uint8Array(4), 1, 1);
    black.needsUpdate = true;
    this.black = black;
    this.targets = {}; // 'lightmap.lit', 'ground.with', 'ground.without', ...
    this.passes = [];
    const t = relighter.targets;
    const bounce = (key) => sunBounce?.texture(key) ?? black;
    const atlases = new Set(Object.keys(t).filter((k) => k.endsWith('.I')).map((k) => k.slice(0, -2)));
    for (const atlas of atlases) {
      const { width, height } = t[`${atlas}.I`];
      const sum = (name, a, wa, b, wb, c) => {
        const target = makeTarget(width, height, relighter.format);
        target.texture.name = `${atlas}.${name}`;
        this.targets[`${atlas}.${name}`] = target;
        this.passes.push({
          target,
          pass: new FullscreenPass({
            fragmentShader: sumFragment(relighter.format.rgbe),
            uniforms: {
              a: { value: a }, b: { value: b ?? black }, c: { value: c }, wa: { value: wa }, wb: { value: wb },
            },
          }),
        });
      };
      const I = t[`${atlas}.I`].texture;
      const D = t[`${atlas}.d`]?.texture;
      if (D) {
        sum('with', D, 1, I, -1, bounce(`${atlas}.I`));
        sum('without', D, 1, null, 0, bounce(`${atlas}.d`));
      } else {
        sum('lit', I, 1, null, 0, bounce(`${atlas}.I`));
      }
    }
  }

  /** The target of an atlas ('ground.with'), or undefined. */
  texture(key) {
    return this.targets[key]?.texture;
  }

  /** Sum again: after a relight or a new sun's bounce. */
  update() {
    for (const { pass, target } of this.passes) pass.render(this.renderer, target);
  }

  dispose() {
    for (const { pass, target } of this.passes) {
      pass.dispose();
      target.dispose();
    }
    this.black.dispose();
  }
}
