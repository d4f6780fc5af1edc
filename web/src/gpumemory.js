// GPU memory the client allocates, counted where it is allocated: the WebGL2 context's
// texture and renderbuffer calls are wrapped, and each allocation is sized from its internal
// format, width, height, layers (depth) and mip levels, per texture object, until it is deleted.
// Every texture and render target of every module is in it, whoever created it (three.js, the
// KTX2 transcoder's uploads, the shadow maps); the canvas's own drawing buffer is not (the
// browser allocates it; `drawingBufferBytes` estimates it). Bytes, not kilobytes.
//
// docs/web.md, "GPU memory"; the test compares it with a count from the manifest.

const GL = WebGL2RenderingContext;

// Sized internal formats: bytes per texel.
const TEXEL_BYTES = new Map([
  [GL.R8, 1], [GL.RG8, 2], [GL.RGB8, 3], [GL.RGBA8, 4], [GL.SRGB8_ALPHA8, 4], [GL.SRGB8, 3],
  [GL.R16F, 2], [GL.RG16F, 4], [GL.RGB16F, 6], [GL.RGBA16F, 8],
  [GL.R32F, 4], [GL.RG32F, 8], [GL.RGB32F, 12], [GL.RGBA32F, 16],
  [GL.R11F_G11F_B10F, 4], [GL.RGB9_E5, 4], [GL.RGB10_A2, 4], [GL.RGBA4, 2], [GL.RGB565, 2],
  [GL.RGB5_A1, 2], [GL.R8UI, 1], [GL.RGBA8UI, 4], [GL.R32UI, 4], [GL.R16UI, 2],
  [GL.DEPTH_COMPONENT16, 2], [GL.DEPTH_COMPONENT24, 4], [GL.DEPTH_COMPONENT32F, 4],
  [GL.DEPTH24_STENCIL8, 4], [GL.DEPTH32F_STENCIL8, 8], [GL.STENCIL_INDEX8, 1],
]);

// Compressed formats: [block width, block height, bytes per block].
const BLOCKS = new Map([
  [0x83f0, [4, 4, 8]], [0x83f1, [4, 4, 8]], [0x83f2, [4, 4, 16]], [0x83f3, [4, 4, 16]], // BC1-3
  [0x8e8c, [4, 4, 16]], [0x8e8d, [4, 4, 16]], // BC7
  [0x9274, [4, 4, 8]], [0x9275, [4, 4, 8]], [0x9278, [4, 4, 16]], [0x9279, [4, 4, 16]], // ETC2
  [0x8d64, [4, 4, 8]], // ETC1
  [0x93b0, [4, 4, 16]], [0x93d0, [4, 4, 16]], // ASTC 4x4
  [0x8dbb, [4, 4, 8]], [0x8dbd, [4, 4, 16]], // RGTC
]);

// Unsized formats (texImage with internalformat RGBA etc.): channels x bytes per channel.
const CHANNELS = new Map([[GL.RGBA, 4], [GL.RGB, 3], [GL.RG, 2], [GL.RED, 1], [GL.ALPHA, 1],
  [GL.LUMINANCE, 1], [GL.LUMINANCE_ALPHA, 2], [GL.DEPTH_COMPONENT, 1]]);
const TYPE_BYTES = new Map([[GL.UNSIGNED_BYTE, 1], [GL.HALF_FLOAT, 2], [GL.FLOAT, 4],
  [GL.UNSIGNED_SHORT, 2], [GL.UNSIGNED_INT, 4], [GL.UNSIGNED_INT_24_8, 4]]);

/** Bytes of one image w x h x d of `internalformat` (`type` for unsized formats). */
export function imageBytes(internalformat, w, h, d = 1, type = GL.UNSIGNED_BYTE) {
  const block = BLOCKS.get(internalformat);
  if (block) return Math.ceil(w / block[0]) * Math.ceil(h / block[1]) * block[2] * d;
  const texel = TEXEL_BYTES.get(internalformat)
    ?? (CHANNELS.get(internalformat) ?? 4) * (TYPE_BYTES.get(type) ?? 1);
  return texel * w * h * d;
}

const FACES = new Set([GL.TEXTURE_CUBE_MAP_POSITIVE_X, GL.TEXTURE_CUBE_MAP_NEGATIVE_X,
  GL.TEXTURE_CUBE_MAP_POSITIVE_Y, GL.TEXTURE_CUBE_MAP_NEGATIVE_Y,
  GL.TEXTURE_CUBE_MAP_POSITIVE_Z, GL.TEXTURE_CUBE_MAP_NEGATIVE_Z]);

export class GpuMemoryMeter {
  /** @param {WebGL2RenderingContext} gl wrapped in place (before anything is allocated) */
  constructor(gl) {
    this.gl = gl;
    this.textures = new Map(); // WebGLTexture -> Map(face:level -> bytes)
    this.renderbuffers = new Map(); // WebGLRenderbuffer -> bytes
    // What each object was last allocated as (internal format, width, height, layers): the
    // breakdown (debug.gpuBreakdown) names it, the totals do not need it.
    this.shapes = new Map(); // WebGLTexture or WebGLRenderbuffer -> {format, w, h, d, samples}
    this.unit = 0;
    this.bound = new Map(); // `${unit}:${target}` -> texture
    this.renderbuffer = null;
    this._wrap();
  }

  get textureBytes() {
    let sum = 0;
    for (const levels of this.textures.values()) for (const b of levels.values()) sum += b;
    return sum;
  }

  get renderbufferBytes() {
    let sum = 0;
    for (const b of this.renderbuffers.values()) sum += b;
    return sum;
  }

  /**
   * Every live allocation: [{object, bytes, format, w, h, d, samples}], largest first; `name`
   * (object -> string or undefined) labels the ones a caller knows (debug.gpuBreakdown).
   */
  allocations(name = () => undefined) {
    const out = [];
    for (const [object, levels] of this.textures) {
      let bytes = 0;
      for (const b of levels.values()) bytes += b;
      out.push({ name: name(object) ?? 'texture', bytes, ...this.shapes.get(object) });
    }
    for (const [object, bytes] of this.renderbuffers) {
      out.push({ name: name(object) ?? 'renderbuffer', bytes, ...this.shapes.get(object) });
    }
    return out.sort((a, b) => b.bytes - a.bytes);
  }

  /** The canvas's drawing buffer: colour and depth-stencil (4 + 4 bytes), x samples. */
  drawingBufferBytes() {
    const gl = this.gl;
    const samples = Math.max(1, gl.getContextAttributes()?.antialias ? 4 : 1);
    return gl.drawingBufferWidth * gl.drawingBufferHeight * 8 * samples;
  }

  _texture(target) {
    const key = FACES.has(target) ? GL.TEXTURE_CUBE_MAP : target;
    return this.bound.get(`${this.unit}:${key}`) ?? null;
  }

  _set(target, key, bytes, shape) {
    const texture = this._texture(target);
    if (!texture) return;
    this.log?.push([target, key, bytes]);
    if (shape) this.shapes.set(texture, shape);
    if (!this.textures.has(texture)) this.textures.set(texture, new Map());
    this.textures.get(texture).set(key, bytes);
  }

  _wrap() {
    const gl = this.gl;
    const meter = this;
    const wrap = (name, after) => {
      const original = gl[name].bind(gl);
      gl[name] = function wrapped(...args) {
        const result = original(...args);
        after(args, result);
        return result;
      };
    };
    wrap('activeTexture', ([unit]) => { meter.unit = unit - GL.TEXTURE0; });
    wrap('bindTexture', ([target, texture]) => { meter.bound.set(`${meter.unit}:${target}`, texture); });
    wrap('deleteTexture', ([texture]) => {
      meter.textures.delete(texture);
      meter.shapes.delete(texture);
    });
    wrap('texStorage2D', ([target, levels, format, w, h]) => {
      const faces = target === GL.TEXTURE_CUBE_MAP ? 6 : 1;
      let bytes = 0;
      for (let l = 0; l < levels; l++) bytes += faces * imageBytes(format, Math.max(1, w >> l), Math.max(1, h >> l));
      meter._set(target, 'storage', bytes, { format, w, h, d: faces, levels });
    });
    wrap('texStorage3D', ([target, levels, format, w, h, d]) => {
      let bytes = 0;
      for (let l = 0; l < levels; l++) {
        const depth = target === GL.TEXTURE_3D ? Math.max(1, d >> l) : d;
        bytes += imageBytes(format, Math.max(1, w >> l), Math.max(1, h >> l), depth);
      }
      meter._set(target, 'storage', bytes, { format, w, h, d, levels });
    });
    wrap('texImage2D', (args) => {
      const [target, level, format] = args;
      let w;
      let h;
      let type;
      if (args.length >= 8) [, , , w, h, , , type] = args;
      else [w, h, type] = [args[5]?.width ?? 0, args[5]?.height ?? 0, args[4]];
      meter._set(target, `${target}:${level}`, imageBytes(format, w, h, 1, type), level ? null : { format, w, h, d: 1, type });
    });
    wrap('texImage3D', ([target, level, format, w, h, d, , , type]) => {
      meter._set(target, `${target}:${level}`, imageBytes(format, w, h, d, type), level ? null : { format, w, h, d, type });
    });
    wrap('compressedTexImage2D', ([target, level, format, w, h]) => {
      meter._set(target, `${target}:${level}`, imageBytes(format, w, h), level ? null : { format, w, h, d: 1 });
    });
    wrap('compressedTexImage3D', ([target, level, format, w, h, d]) => {
      meter._set(target, `${target}:${level}`, imageBytes(format, w, h, d), level ? null : { format, w, h, d });
    });
    // The levels generateMipmap allocates below a texImage's level 0 (texStorage counted its
    // own levels already); a 2D array's layers stay, each level halves width and height.
    wrap('generateMipmap', ([target]) => {
      const texture = meter._texture(target);
      const shape = texture && meter.shapes.get(texture);
      if (!shape || shape.levels || (shape.w <= 1 && shape.h <= 1)) return;
      const faces = target === GL.TEXTURE_CUBE_MAP ? 6 : 1;
      for (let l = 1; (shape.w >> l) > 0 || (shape.h >> l) > 0; l++) {
        const w = Math.max(1, shape.w >> l);
        const h = Math.max(1, shape.h >> l);
        const d = target === GL.TEXTURE_3D ? Math.max(1, shape.d >> l) : shape.d;
        meter._set(target, `mip:${l}`, faces * imageBytes(shape.format, w, h, d, shape.type));
      }
    });
    wrap('bindRenderbuffer', ([, rb]) => { meter.renderbuffer = rb; });
    wrap('deleteRenderbuffer', ([rb]) => {
      meter.renderbuffers.delete(rb);
      meter.shapes.delete(rb);
    });
    const storage = (format, w, h, samples) => {
      if (!meter.renderbuffer) return;
      meter.renderbuffers.set(meter.renderbuffer, Math.max(1, samples) * imageBytes(format, w, h));
      meter.shapes.set(meter.renderbuffer, { format, w, h, d: 1, samples });
    };
    wrap('renderbufferStorage', ([, format, w, h]) => storage(format, w, h, 0));
    wrap('renderbufferStorageMultisample', ([, samples, format, w, h]) => storage(format, w, h, samples));
  }
}
