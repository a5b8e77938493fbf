// Errors a decoder reports: one line each, naming what is wrong and where. The class names are those of
// spec/gspc-format.md: FormatError and its subclasses for the container (section 8), CodecError for the
// payloads (section 10, "refuse").

/** Base class: anything a .gspc file (or a caller's input) can cause. */
export class GspcError extends Error {
  constructor(message) {
    super(message);
    this.name = new.target.name;
  }
}

/** The container (spec sections 2-9) is not a valid gspc file. */
export class FormatError extends GspcError {}

/** The file ends before the region the header declares (spec 8, checks 1-3 and 8). */
export class Truncated extends FormatError {}
/** The magic or the end marker is wrong (spec 8, checks 1 and 10). */
export class BadMagic extends FormatError {}
/** A major version this reader does not implement (spec 3). */
export class UnsupportedVersion extends FormatError {}
/** A length or count beyond the limits of spec section 7. */
export class LimitExceeded extends FormatError {}
/** The msgpack header breaks a rule of spec sections 4 and 5. */
export class BadHeader extends FormatError {}
/** A CRC-32 differs from the one stored (header, chunk or whole file). */
export class ChecksumMismatch extends FormatError {}
/** Two chunk table entries with the same (type, index). */
export class DuplicateChunk extends FormatError {}
/** A required chunk of a type this reader does not know. */
export class UnknownRequiredChunk extends FormatError {}
/** Bytes after the trailer. */
export class TrailingBytes extends FormatError {}
/** A padding byte that is not zero. */
export class BadPadding extends FormatError {}

/** A payload inside a valid container that a decoder must refuse (spec section 10). */
export class CodecError extends GspcError {}

/** A value for an error message, cut short: a hostile header may hold megabytes in one field. */
export function show(value) {
  let text;
  if (typeof value === 'string') text = `'${value.replace(/[\\']/g, '\\$&').replace(/[\u0000-\u001f]/g, '?')}'`;
  else if (typeof value === 'bigint') text = value.toString();
  else if (value instanceof Uint8Array) text = `<${value.length} bytes>`;
  else if (value instanceof Map) text = `<map of ${value.size}>`;
  else if (Array.isArray(value)) text = `[${value.slice(0, 8).map(show).join(', ')}${value.length > 8 ? ', ...' : ''}]`;
  else text = String(value);
  return text.length <= 60 ? text : `${text.slice(0, 57)}...`;
}
