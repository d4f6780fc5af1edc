// The build over HTTP: the manifest, then the files it lists, each requested as
// /build/PATH?v=<first 16 hex of its sha256> so the server may let the browser cache it as
// immutable (docs/server.md, HTTP). Each file's bytes are checked against the manifest's
// SHA-256 (SubtleCrypto) before use: a mismatch (a damaged copy in the browser's cache or on the
// way) is fetched once more bypassing the cache (`cache: 'reload'`, which also replaces the
// cached copy), and a second mismatch is an error that names the file. SubtleCrypto exists
// only in a secure context (HTTPS, or localhost): on plain HTTP from another address only the
// length is checked (`verification` says which; docs/web.md, "Integrity"). Counts the bytes
// it transfers as they arrive (the HUD shows them while loading, the benchmark reports them)
// and turns every failure into an AssetError that names the file.
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { DataUtils } from 'three';

export class AssetError extends Error {
  constructor(path, reason) {
    super(`Could not load ${path}: ${reason}`);
    this.path = path;
  }
}

const TRANSCODER_PATH = '/vendor/three/examples/jsm/libs/basis/';

export class Assets {
  /**
   * @param {string} manifestUrl e.g. '/build/manifest.json' (the hello's `manifest`)
   * @param {{textureMode?: string}} options textureMode (the page's `?textures=`): 'exact'
   *   (default) transcodes the UASTC data to plain RGBA8 so the GPU reads exactly the texels the
   *   numpy reference reads (docs/web.md, "Texture formats"), and ETC1S data to ETC2 blocks
   *   where the GPU has them (lossless); 'astc' as 'exact' but the UASTC data as ASTC 4x4
   *   blocks where the GPU has them (a quarter of the memory; the GPU interpolates their
   *   texels in 16 bits where the reference rounds to 8: docs/web.md "Texture formats");
   *   'rgba8' decodes every file to RGBA8, ETC1S too (as before 2026-11-25); 'gpu' lets
   *   KTX2Loader pick a compressed GPU format.
   *   onProgress(bytesLoaded): called as the bytes of each file arrive (assignable later,
   *   `assets.onProgress = null` to stop).
   */
  constructor(manifestUrl = '/build/manifest.json', options = {}) {
    this.manifestUrl = manifestUrl;
    this.base = new URL('.', new URL(manifestUrl, location.href)).href;
    this.textureMode = options.textureMode ?? 'exact';
    this.manifest = null;
    this.files = new Map(); // path -> {bytes, sha256}
    this.bytesLoaded = 0;
    this.onProgress = options.onProgress ?? null;
    this.requests = 0;
    this.refetched = []; // paths whose first copy did not match the manifest
    // 'sha256' where SubtleCrypto is available (a secure context), else 'length'.
    this.verification = globalThis.crypto?.subtle ? 'sha256' : 'length';
    this.ktx2 = null;
    this._inFlight = new Map(); // path -> Promise of its bytes, while on the way
  }

  async loadManifest() {
    let response;
    try {
      // index.html asked for it before the modules came: take that request, once.
      const early = globalThis.daylitEarly;
      globalThis.daylitEarly = null;
      const same = early && new URL(early.url, location.href).href === new URL(this.manifestUrl, location.href).href;
      response = same ? await early.response.catch(() => null) : null;
      response ??= await fetch(this.manifestUrl, { cache: 'no-cache' });
    } catch (err) {
      throw new AssetError('the build manifest', `network error (${err.message})`);
    }
    if (!response.ok) throw new AssetError(this.manifestUrl, `HTTP ${response.status}`);
    const text = await response.text();
    this.bytesLoaded += text.length;
    this.requests += 1;
    let manifest;
    try {
      manifest = JSON.parse(text);
    } catch {
      throw new AssetError(this.manifestUrl, 'not JSON');
    }
    // Version 2 (2026-11-24): a stack's base may also have an ETC1S array (compact.etc1s);
    // 3 (2026-12-06): shared sun-bounce images (lights.image); 4 (2026-12-06): a stack's V
    // may be float16 (compact.v.dtype, read by `matrix`). Docs/manifest.md.
    if (manifest.format !== 'daylit-build' || ![1, 2, 3, 4, 5].includes(manifest.version)) {
      throw new AssetError(this.manifestUrl, `not a daylit build of version 1 to 5 (${manifest.format} ${manifest.version})`);
    }
    this.manifest = manifest;
    this.files = new Map(manifest.files.map((f) => [f.path, f]));
    return manifest;
  }

  /** The URL of a build file, with its checksum query when the manifest lists one. */
  url(path) {
    const entry = this.files.get(path);
    const u = new URL(path, this.base);
    if (entry && entry.sha256) u.searchParams.set('v', entry.sha256.slice(0, 16));
    return u.href;
  }

  /** A build file's bytes, checked against the manifest (fetched again once on a mismatch).
   * Asked for twice at once (the ground's two stacks share their gain), it is fetched once. */
  bytes(path) {
    let pending = this._inFlight.get(path);
    if (!pending) {
      pending = this._bytes(path).finally(() => this._inFlight.delete(path));
      this._inFlight.set(path, pending);
    }
    return pending.then((buffer) => buffer.slice(0)); // each user its own copy (workers take them)
  }

  async _bytes(path) {
    const entry = this.files.get(path);
    let buffer = await this._fetch(path, 'default');
    let problem = entry ? await this._mismatch(entry, buffer) : null;
    if (problem) {
      // A damaged copy (the HTTP cache's, or the network's): once more from the server.
      this.refetched.push(path);
      console.warn(`daylit: ${path}: ${problem}; fetching it again, bypassing the cache`);
      buffer = await this._fetch(path, 'reload');
      problem = await this._mismatch(entry, buffer);
      if (problem) throw new AssetError(path, `${problem}, also when fetched again (the file is damaged on the server or on the way)`);
    }
    return buffer;
  }

  async _fetch(path, cache) {
    let response;
    try {
      response = await fetch(this.url(path), { cache });
    } catch (err) {
      throw new AssetError(path, `network error (${err.message})`);
    }
    if (response.status === 503 && response.headers.get('Cache-Control') === 'no-store') {
      // The server found the file does not match the manifest (docs/server.md, Integrity).
      throw new AssetError(path, 'the file is damaged on the server (HTTP 503); the operator must repair the build');
    }
    if (!response.ok) throw new AssetError(path, `HTTP ${response.status}`);
    const buffer = await this._read(response, path);
    this.requests += 1;
    return buffer;
  }

  /** Why `buffer` is not the file `entry` lists ({bytes, sha256}), or null if it is. */
  async _mismatch(entry, buffer) {
    if (entry.bytes !== buffer.byteLength) {
      return `${buffer.byteLength} bytes, the manifest says ${entry.bytes}`;
    }
    if (this.verification !== 'sha256' || !entry.sha256) return null;
    const digest = new Uint8Array(await crypto.subtle.digest('SHA-256', buffer));
    const hex = Array.from(digest, (b) => b.toString(16).padStart(2, '0')).join('');
    return hex === entry.sha256 ? null : `SHA-256 ${hex.slice(0, 16)}…, the manifest says ${entry.sha256.slice(0, 16)}…`;
  }

  /** The body as an ArrayBuffer, counted into bytesLoaded chunk by chunk as it arrives. */
  async _read(response, path) {
    if (!response.body) {
      const buffer = await response.arrayBuffer();
      this._count(buffer.byteLength);
      return buffer;
    }
    const chunks = [];
    let length = 0;
    const reader = response.body.getReader();
    try {
      for (;;) {
        const { done, value } = await reader.read();
        if (done) break;
        chunks.push(value);
        length += value.byteLength;
        this._count(value.byteLength);
      }
    } catch (err) {
      throw new AssetError(path, `network error (${err.message})`);
    }
    const bytes = new Uint8Array(length);
    let at = 0;
    for (const c of chunks) {
      bytes.set(c, at);
      at += c.byteLength;
    }
    return bytes.buffer;
  }

  _count(n) {
    this.bytesLoaded += n;
    this.onProgress?.(this.bytesLoaded);
  }

  /** Whether the basis data reach the GPU exactly as the reference decodes them (every mode
   * but 'gpu'). */
  get exactTextures() {
    return this.textureMode !== 'gpu';
  }

  /** Set up the Basis transcoder for this renderer (once) and start fetching it (its wasm is
   * the largest file before the first picture: not after the manifest, beside it). */
  initTextures(renderer) {
    this.ktx2 = new KTX2Loader().setTranscoderPath(TRANSCODER_PATH).detectSupport(renderer);
    this.etc1sFormat = this.exactTextures ? 'rgba8' : 'gpu'; // 'gpu': KTX2Loader's pick
    this.uastcFormat = this.exactTextures ? 'rgba8' : 'gpu';
    if (this.exactTextures) {
      // Basis data are numbers, not pictures: UASTC decodes to RGBA8 exactly as the reference
      // does (ASTC, BC7 or ETC2 targets would add their own error to every basis value).
      // The extension itself, not KTX2Loader's etc2Supported, which it turns off wherever ASTC,
      // ETC2, BPTC and S3TC all show (Mesa's desktop drivers emulate ETC2 by decoding it on
      // upload; so does SwiftShader, exactly). Phones decode ETC2 in hardware (OpenGL ES 3.0).
      const etc2 = renderer.extensions.has('WEBGL_compressed_texture_etc') && this.textureMode !== 'rgba8';
      // UASTC is a subset of ASTC 4x4: the blocks go to the GPU as they are, 1 byte a texel.
      const astc = renderer.extensions.has('WEBGL_compressed_texture_astc') && this.textureMode === 'astc';
      for (const key of Object.keys(this.ktx2.workerConfig)) {
        if (key.endsWith('Supported')) this.ktx2.workerConfig[key] = astc && key === 'astcSupported';
      }
      if (astc) this.uastcFormat = 'astc';
      // ETC1S is a subset of ETC1, so an ETC1S file goes to the GPU as ETC2 RGB8 blocks with
      // no loss: the GPU decodes the very texels basisu's RGBA8 decode gives (integer
      // arithmetic, the same blocks), at half a byte a texel instead of four (docs/web.md,
      // "GPU memory"). A second loader, since the transcoder's targets are set per loader.
      if (etc2 || astc) { // ETC1S never to ASTC: ETC2 blocks or RGBA8
        this.ktx2Etc1s = new KTX2Loader().setTranscoderPath(TRANSCODER_PATH).setWorkerLimit(2).detectSupport(renderer);
        for (const key of Object.keys(this.ktx2Etc1s.workerConfig)) {
          if (key.endsWith('Supported')) this.ktx2Etc1s.workerConfig[key] = etc2 && key === 'etc2Supported';
        }
        this.ktx2Etc1s.init().catch(() => {});
        if (etc2) this.etc1sFormat = 'etc2';
      }
    }
    this.ktx2.init().catch(() => {}); // a failure is reported by the first texture's parse
  }

  /** A KTX2 texture (2D, or a 2D array for several layers), linear, unfiltered reads. */
  async texture(path) {
    const buffer = await this.bytes(path);
    // supercompressionScheme (KTX2 header, byte 44): 1 is BasisLZ, i.e. ETC1S
    const etc1s = buffer.byteLength >= 48 && new DataView(buffer).getUint32(44, true) === 1;
    const loader = etc1s && this.ktx2Etc1s ? this.ktx2Etc1s : this.ktx2;
    const texture = await new Promise((resolve, reject) => {
      loader.parse(buffer, resolve, (err) => reject(new AssetError(path, `KTX2 transcoding failed (${err?.message ?? err})`)));
    });
    texture.name = path;
    return texture;
  }

  /** One texture for every user of a file (the gain array a shadowing atlas's I and d stacks
   * share: uploaded once, not once per stack). Disposed by its users: a second dispose of a
   * three.js texture does nothing. */
  sharedTexture(path) {
    this._shared ??= new Map();
    if (!this._shared.has(path)) {
      this._shared.set(path, this.texture(path).catch((err) => {
        this._shared.delete(path); // asked again later, fetched again
        throw err;
      }));
    }
    return this._shared.get(path);
  }

  /** A float32 little-endian array. */
  async float32(path) {
    const buffer = await this.bytes(path);
    if (buffer.byteLength % 4) throw new AssetError(path, 'not a float32 array');
    return new Float32Array(buffer);
  }

  /**
   * A stack's V matrix (manifest `compact.v` or `compact.coarse.v`: {path, shape, dtype,
   * scale or scales}) as a Float32Array, n x k row-major: `float32-le` as it is; `float16-le`
   * (builds of version 4) widened (three.js DataUtils.fromHalfFloat) and times `scale`, a
   * power of two; `int8` (version 5) times its column's `scales[j]`. Each product is exact in
   * a double, so its float32 is the same value as bake/compact_reader.py's read_v.
   * Little-endian files.
   */
  async matrix(v) {
    const dtype = v.dtype ?? 'float32-le';
    if (dtype === 'float32-le') return this.float32(v.path);
    if (dtype === 'int8') return this.int8Matrix(v);
    if (dtype !== 'float16-le') throw new AssetError(v.path, `V of an unknown type ${dtype}`);
    const buffer = await this.bytes(v.path);
    if (buffer.byteLength % 2) throw new AssetError(v.path, 'not a float16 array');
    const view = new DataView(buffer);
    const scale = v.scale ?? 1;
    const out = new Float32Array(buffer.byteLength / 2);
    for (let i = 0; i < out.length; i++) out[i] = DataUtils.fromHalfFloat(view.getUint16(2 * i, true)) * scale;
    return out;
  }

  /** An `int8` V (see `matrix`): each entry times its column's scale. */
  async int8Matrix(v) {
    const [n, k] = v.shape;
    const buffer = await this.bytes(v.path);
    if (buffer.byteLength !== n * k) throw new AssetError(v.path, `${buffer.byteLength} bytes, expected ${n} x ${k} int8 values`);
    if (!Array.isArray(v.scales) || v.scales.length !== k) throw new AssetError(v.path, `int8 V without its ${k} column scales`);
    const values = new Int8Array(buffer);
    const out = new Float32Array(n * k);
    for (let i = 0; i < n; i++) {
      for (let j = 0; j < k; j++) out[i * k + j] = values[i * k + j] * v.scales[j];
    }
    return out;
  }

  async gltf(path) {
    const buffer = await this.bytes(path);
    try {
      return await new GLTFLoader().parseAsync(buffer, this.base);
    } catch (err) {
      throw new AssetError(path, `not a readable glTF (${err.message})`);
    }
  }

  /** A PNG as raw pixels (no colour management, no premultiplication): {width, height, data}. */
  async image(path) {
    const buffer = await this.bytes(path);
    let bitmap;
    try {
      bitmap = await createImageBitmap(new Blob([buffer]), {
        colorSpaceConversion: 'none', premultiplyAlpha: 'none',
      });
    } catch (err) {
      throw new AssetError(path, `not a readable image (${err.message})`);
    }
    return bitmap;
  }

  dispose() {
    this.ktx2?.dispose();
    this.ktx2Etc1s?.dispose();
  }
}
