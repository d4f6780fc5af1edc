// The light stream's wire format, protocol versions 1, 2 and 3 (docs/protocol.md).
// A pure ES module: no DOM, no network; the web client and the Node tests import it.
//
// Binary messages are little-endian: a 24-byte header
//   0 magic "DLYT" | 4 u8 version | 5 u8 type | 6 u16 flags | 8 u32 sequence
//   12 u32 count | 16 f64 capture time (Unix seconds)
// then, for LIGHT of version 2 or 3, the sun (28 bytes):
//   24 f32[3] direction (unit, site frame +X east, +Y up, -Z north; zeros when none)
//   36 f32[3] normal irradiance RGB, W/m^2 | 48 u8 source (0 none, 1 measured, 2 model,
//   3 scene) | 49 u8[3] reserved
// then the sky: versions 1 and 2 count x RGB float32 (version 2 without the sun's disc),
// version 3 count x RGB IEEE float16 (halfToFloat), and a saturated bitmask of
// ceil(count / 8) bytes (bit i % 8 of byte i >> 3, least significant bit first); for other
// types, count bytes. This client asks for version 3 (lightStreamUrl) and reads versions 1
// (an older server: sun null) and 2 (a server of 2026-11 before version 3) as well.

export const PROTOCOL_VERSION = 3;
export const SUPPORTED_VERSIONS = Object.freeze([1, 2, 3]);
// What to ask an older server that refuses ?protocol=3 (HTTP 400): see LightStream.
export const FALLBACK_VERSION = 2;
export const SUN_BYTES = 28;
export const SUN_SOURCES = Object.freeze(['none', 'measured', 'model', 'scene']);
export const MAGIC = 'DLYT';
export const HEADER_BYTES = 24;

export const MessageType = Object.freeze({
  LIGHT: 1,
  SITE_CAMERA: 2,
  OCCLUSION_MASK: 3, // people in front of virtual objects (docs/occlusion.md)
});

export const Flags = Object.freeze({
  STALE: 1,
  SATURATED: 2,
  SIMULATED: 4,
  REPLAY: 8,
  LEARNING: 16,
  SUN_ESTIMATED: 32,
});

const TYPE_NAMES = { 1: 'light', 2: 'site-camera', 3: 'occlusion-mask' };

export class ProtocolError extends Error {}

function asDataView(data) {
  if (data instanceof ArrayBuffer) return new DataView(data);
  if (ArrayBuffer.isView(data)) return new DataView(data.buffer, data.byteOffset, data.byteLength);
  throw new ProtocolError('expected an ArrayBuffer or a typed array');
}

/**
 * An IEEE 754 binary16 value from its 16 bits: sign, 5 exponent bits (bias 15), 10 fraction
 * bits. Exact (every half is a float32). (Node 20 has no DataView.getFloat16.)
 * @param {number} h 0..65535
 * @returns {number}
 */
export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 31;
  const f = h & 1023;
  if (e === 0) return sign * f * 2 ** -24; // zero and subnormals
  if (e === 31) return f ? NaN : sign * Infinity;
  return sign * (1024 + f) * 2 ** (e - 25);
}

/**
 * Decode one binary message.
 * @param {ArrayBuffer|ArrayBufferView} data
 * @returns {{type:number, typeName:string, version:number, flags:number, stale:boolean,
 *   saturatedFlag:boolean, simulated:boolean, replay:boolean, sequence:number,
 *   captureTime:number, count:number, rgb?:Float32Array, saturated?:Uint8Array,
 *   sun?:({direction:number[], normalIrradiance:number[], source:string,
 *   estimated:boolean}|null), payload?:Uint8Array}}
 *   rgb holds count x 3 values (light-major) whatever the encoding; saturated[i] is 1 when
 *   light i clipped; sun (LIGHT only) is null in version 1 (the sun is then inside its
 *   patch's value).
 * @throws {ProtocolError} when the message is malformed.
 */
export function decodeMessage(data) {
  const view = asDataView(data);
  if (view.byteLength < HEADER_BYTES) {
    throw new ProtocolError(`message of ${view.byteLength} bytes is shorter than the header`);
  }
  const magic = String.fromCharCode(
    view.getUint8(0), view.getUint8(1), view.getUint8(2), view.getUint8(3));
  if (magic !== MAGIC) throw new ProtocolError('bad magic');
  const version = view.getUint8(4);
  if (!SUPPORTED_VERSIONS.includes(version)) {
    throw new ProtocolError(`unsupported protocol version ${version}`);
  }
  const type = view.getUint8(5);
  const flags = view.getUint16(6, true);
  const msg = {
    type,
    typeName: TYPE_NAMES[type] ?? 'unknown',
    version,
    flags,
    stale: (flags & Flags.STALE) !== 0,
    saturatedFlag: (flags & Flags.SATURATED) !== 0,
    simulated: (flags & Flags.SIMULATED) !== 0,
    replay: (flags & Flags.REPLAY) !== 0,
    sequence: view.getUint32(8, true),
    count: view.getUint32(12, true),
    captureTime: view.getFloat64(16, true),
  };
  const bodyBytes = view.byteLength - HEADER_BYTES;
  if (type === MessageType.LIGHT) {
    const n = msg.count;
    const sunBytes = version >= 2 ? SUN_BYTES : 0;
    const perLight = version >= 3 ? 6 : 12;
    const need = sunBytes + perLight * n + ((n + 7) >> 3);
    if (bodyBytes !== need) {
      throw new ProtocolError(`light message of ${n} lights needs ${need} payload bytes`);
    }
    msg.sun = null;
    if (sunBytes) {
      const f = (k) => view.getFloat32(HEADER_BYTES + 4 * k, true);
      const source = view.getUint8(HEADER_BYTES + 24);
      msg.sun = {
        direction: [f(0), f(1), f(2)],
        normalIrradiance: [f(3), f(4), f(5)],
        source: SUN_SOURCES[source] ?? 'unknown',
        estimated: (flags & Flags.SUN_ESTIMATED) !== 0,
      };
    }
    const start = HEADER_BYTES + sunBytes;
    const rgb = new Float32Array(3 * n);
    if (version >= 3) {
      for (let i = 0; i < 3 * n; i++) rgb[i] = halfToFloat(view.getUint16(start + 2 * i, true));
    } else {
      for (let i = 0; i < 3 * n; i++) rgb[i] = view.getFloat32(start + 4 * i, true);
    }
    const saturated = new Uint8Array(n);
    const maskStart = start + perLight * n;
    for (let i = 0; i < n; i++) {
      saturated[i] = (view.getUint8(maskStart + (i >> 3)) >> (i & 7)) & 1;
    }
    msg.rgb = rgb;
    msg.saturated = saturated;
  } else {
    if (bodyBytes !== msg.count) {
      throw new ProtocolError(`payload is ${bodyBytes} bytes, header says ${msg.count}`);
    }
    msg.payload = new Uint8Array(view.buffer, view.byteOffset + HEADER_BYTES, bodyBytes);
  }
  return msg;
}

/**
 * Parse the server's first (text) message.
 * @param {string} text
 * @returns {object} the hello: protocol, scene, lights, manifest, streams, ...
 */
export function parseHello(text) {
  let hello;
  try {
    hello = JSON.parse(text);
  } catch {
    throw new ProtocolError('hello is not JSON');
  }
  if (!hello || hello.type !== 'hello') throw new ProtocolError('expected a hello message');
  if (!SUPPORTED_VERSIONS.includes(hello.protocol)) {
    throw new ProtocolError(
      `server speaks protocol ${hello.protocol}, client ${SUPPORTED_VERSIONS.join(' or ')}`);
  }
  if (!Number.isInteger(hello.lights) || hello.lights < 1) {
    throw new ProtocolError('hello has no light count');
  }
  return hello;
}

/** The text message that selects streams, e.g. ['light', 'site-camera']. */
export function subscribeMessage(streams) {
  return JSON.stringify({ type: 'subscribe', streams });
}

/** A ping; the server answers {type: 'pong', id, server_time_s}. */
export function pingMessage(id) {
  return JSON.stringify({ type: 'ping', id });
}

/**
 * WebSocket URL of the light stream for a page at `location` (an URL or Location), asking
 * for protocol `version` (default the newest, 3; a server that only knows version 1 ignores
 * the parameter, one that knows 1 and 2 refuses 3 with HTTP 400: ask FALLBACK_VERSION).
 */
/**
 * The light stream's URL. `token`: the operator's token a kiosk carries (its page's
 * `?token=`), without which the server withholds the site-camera and occlusion streams
 * (docs/protocol.md, "Connecting").
 */
export function lightStreamUrl(location, streams = ['light'], version = PROTOCOL_VERSION, token = null) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const params = [`protocol=${version}`];
  if (streams.length) params.push(`streams=${streams.join(',')}`);
  if (token) params.push(`token=${encodeURIComponent(token)}`);
  return `${scheme}//${location.host}/ws/light?${params.join('&')}`;
}

// ------------------------------------------------------------------------------------------
// OCCLUSION_MASK payload (message type 3, docs/occlusion.md "Wire format"), little-endian:
//   0 u8 codec version (1) | 1 u8 encoding (1 = raster run lengths) | 2 u16 width
//   4 u16 height | 6 u16 people in front | 8.. unsigned LEB128 run lengths to the end.
// Runs alternate clear / set starting with clear (0 when the first pixel is set), top row
// first, left to right, and add up to width * height exactly.

export const MASK_CODEC_VERSION = 1;
export const MASK_ENCODING_RUNS = 1;
const MASK_HEADER_BYTES = 8;
const MAX_VARINT_BYTES = 5;

/**
 * Decode an OCCLUSION_MASK payload (msg.payload of a type-3 message).
 * @param {Uint8Array} payload
 * @returns {{width:number, height:number, people:number, mask:Uint8Array, setCount:number}}
 *   mask holds width * height bytes, 255 where a person stands in front (rows from the top).
 * @throws {ProtocolError} when the payload does not follow the layout.
 */
export function decodeOcclusionMask(payload) {
  const bytes = payload instanceof Uint8Array ? payload : new Uint8Array(payload);
  if (bytes.byteLength < MASK_HEADER_BYTES) {
    throw new ProtocolError(`mask payload of ${bytes.byteLength} bytes is shorter than the 8-byte header`);
  }
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const version = view.getUint8(0);
  const encoding = view.getUint8(1);
  const width = view.getUint16(2, true);
  const height = view.getUint16(4, true);
  const people = view.getUint16(6, true);
  if (version !== MASK_CODEC_VERSION) throw new ProtocolError(`unsupported mask codec version ${version}`);
  if (encoding !== MASK_ENCODING_RUNS) throw new ProtocolError(`unknown mask encoding ${encoding}`);
  if (width === 0 || height === 0) throw new ProtocolError(`empty mask size ${width}x${height}`);
  const total = width * height;
  const mask = new Uint8Array(total);
  let pos = 0; // pixels written
  let runIndex = 0;
  let setCount = 0;
  let i = MASK_HEADER_BYTES;
  while (i < bytes.byteLength) {
    // One LEB128 varint (at most 5 bytes, 7 bits a byte, least significant group first).
    let value = 0;
    let shift = 0;
    let used = 0;
    for (;;) {
      if (i >= bytes.byteLength) throw new ProtocolError('truncated varint at the end of the runs');
      if (used === MAX_VARINT_BYTES) throw new ProtocolError(`varint longer than ${MAX_VARINT_BYTES} bytes`);
      const b = bytes[i++];
      value += (b & 0x7f) * 2 ** shift; // not <<: 5 groups reach 35 bits
      shift += 7;
      used += 1;
      if ((b & 0x80) === 0) break;
    }
    if (runIndex > 0 && value === 0) throw new ProtocolError('zero-length run after the first');
    if (pos + value > total) throw new ProtocolError(`runs cover more than the ${total} pixels of the mask`);
    if (runIndex % 2 === 1) {
      mask.fill(255, pos, pos + value);
      setCount += value;
    }
    pos += value;
    runIndex += 1;
  }
  if (runIndex === 0) throw new ProtocolError('no runs');
  if (pos !== total) throw new ProtocolError(`runs cover ${pos} pixels, the mask has ${total}`);
  return { width, height, people, mask, setCount };
}
