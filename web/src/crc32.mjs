// CRC-32/ISO-HDLC (spec section 1): the checksum of zlib, gzip and PNG. Reflected polynomial 0xEDB88320,
// initial value and final XOR 0xFFFFFFFF. Slicing by eight: the file checksum covers every byte of a file.

const TABLES = (() => {
  const t = new Int32Array(8 * 256);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    t[n] = c;
  }
  for (let n = 0; n < 256; n++) {
    for (let s = 1; s < 8; s++) t[s * 256 + n] = (t[(s - 1) * 256 + n] >>> 8) ^ t[t[(s - 1) * 256 + n] & 0xff];
  }
  return t;
})();

/** The CRC-32 of `bytes` (a Uint8Array), continuing from `crc` (the CRC of the bytes before them). */
export function crc32(bytes, crc = 0) {
  let c = ~crc; // an int32 throughout: the table lookups and XORs never leave 32 bits
  let i = 0;
  const n = bytes.length;
  const end8 = n - (n % 8);
  const t = TABLES;
  for (; i < end8; i += 8) {
    const a = c ^ (bytes[i] | (bytes[i + 1] << 8) | (bytes[i + 2] << 16) | (bytes[i + 3] << 24));
    c =
      t[1792 + (a & 0xff)] ^
      t[1536 + ((a >>> 8) & 0xff)] ^
      t[1280 + ((a >>> 16) & 0xff)] ^
      t[1024 + (a >>> 24)] ^
      t[768 + bytes[i + 4]] ^
      t[512 + bytes[i + 5]] ^
      t[256 + bytes[i + 6]] ^
      t[bytes[i + 7]];
  }
  for (; i < n; i++) c = t[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return ~c >>> 0;
}
