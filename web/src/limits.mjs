// Every limit the decoder checks, in one place. A .gspc file is untrusted: each count and size it declares
// is compared with a number here before anything in proportion to it is allocated or decoded, so that the
// work of decoding a file is bounded by a constant plus a multiple of its size (spec 7 and 10.10). Each
// entry names the spec section that states it and why it is that number.

// --- container (spec section 7) ---------------------------------------------------------------------------

// header_length: the header holds the chunk table and meta; 2^24 keeps a reader from buffering more than
// 16 MiB on the word of 4 bytes.
export const MAX_HEADER_LENGTH = 2 ** 24;
// Chunks in the table: a 16-bit count, room for a 1.0-layout RESI chunk per view of any capture.
export const MAX_CHUNKS = 65535;
// One chunk's length: 2^48 - 1 keeps every offset exact in binary64 and in 64-bit integers.
export const MAX_CHUNK_LENGTH = 2 ** 48 - 1;
// index, flags and crc are 32-bit quantities.
export const MAX_U32 = 2 ** 32 - 1;
// msgpack nesting of the header (and of the payloads, 10.0): the top-level map is level 1; a recursive
// reader must not be driven into a stack overflow.
export const MAX_DEPTH = 32;

// --- attribute codec (spec 10.0, 10.10) -------------------------------------------------------------------

// Gaussians N: 1 .. 2^26, and at most max(2^16, floor(8 P / 12)) for P bytes of attribute payloads (10.10).
// A row whose models are all constant costs no bits, so N alone would let a 1 KB file ask for any
// allocation; beyond the floor every Gaussian must code at least 12 bits.
export const MAX_GAUSSIANS = 2 ** 26;
export const GAUSSIAN_FLOOR = 2 ** 16;
export const MIN_CODED_BITS_PER_GAUSSIAN = 12;
/** The most Gaussians attribute payloads of `payloadBytes` bytes in all may declare (10.10). */
export function maxCodedGaussians(payloadBytes) {
  return Math.max(GAUSSIAN_FLOOR, Math.floor((8 * payloadBytes) / MIN_CODED_BITS_PER_GAUSSIAN));
}

// SH degree 0..3 (10.0): the INRIA layout stops at degree 3.
export const MAX_SH_DEGREE = 3;
// Position bits per axis (10.0): 3 x 17 = 51 bits per Morton code on a plain grid; 3 x 21 = 63 on a
// contracted one, whose far octaves need the extra bits.
export const MAX_BITS_PLAIN = 17;
export const MAX_BITS_CONTRACTED = 21;
// Position bounds (10.1): world coordinates within 2^64 and contracted grid coordinates within 32 keep every
// binary64 step of the position decoding finite and every decoded coordinate a finite binary32.
export const MAX_COORDINATE = 2 ** 64;
/** The largest quantiser step (10.0): every decoded value stays a finite binary32. */
export const MAX_STEP = 2 ** 64;
/** binary32's relative resolution (10.1): a position grid spans at least this fraction of its corners. */
export const RESOLUTION = 2 ** -24;
export const MAX_CONTRACTED = 32;
// Precision classes (10.0, 10.13): class 0 and at most 15 maps; each class is a matrix per chunk, so the
// count bounds the matrices a file may ask for.
export const MAX_CLASSES = 16;
// Codebook entries of an attribute section at version 5 (spec 10.16), and at most its count n.
export const MAX_CODEBOOK = 2 ** 16;

// Model integers and decoded matrix entries (10.0, 10.11): -2^48 .. 2^48, so a prediction (a sum of three
// of them) stays inside 64 bits and every value converts to binary64 exactly. Also the bound of the levels
// L and M.
export const MAX_CODEC_INT = 2 ** 48;
// Model window S (10.0): 2 .. 2^22 symbols: the size of one probability table and the work to build it.
export const MIN_WINDOW = 2;
export const MAX_WINDOW = 2 ** 22;
// Explicit weights of a kind-3 model (10.0): each below 2^39, so a window's sum stays below 2^61.
export const MAX_WEIGHT_EXCLUSIVE = 2 ** 39;
// Kind-2 models (10.0): ratio index u 0..130 (131 ratios), centre boost index b 0..21 (22 boosts).
export const MAX_RATIO_INDEX = 130;
export const MAX_BOOST_INDEX = 21;
// Probabilities have 24 bits (10.0): every table sums to 2^24.
export const PROBABILITY_BITS = 24;

// Probability-table entries of one matrix, or at version 4 of one chunk's matrices together (10.0, 10.10):
// the windows of its kind-2 and kind-3 models sum to at most max(2^22, 16 E) for E payload bytes. A
// six-integer model asks for 2^22 entries; the floor is one table of the widest window.
export const MODEL_TABLE_FLOOR = 2 ** 22;
export const MODEL_ENTRIES_PER_BYTE = 16;
/** The most table entries the models of a payload of `payloadBytes` bytes may build (10.0). */
export function maxModelEntries(payloadBytes) {
  return Math.max(MODEL_TABLE_FLOOR, MODEL_ENTRIES_PER_BYTE * payloadBytes);
}

// A matrix's `models` zstd frame of Z bytes holds at most min(2^26, max(2^16, 32 Z)) bytes (10.0): zstd can
// expand a frame thousands of times, and every byte of the model list is parsed and checked.
export const MODEL_LIST_FLOOR = 2 ** 16;
export const MODEL_LIST_RATIO = 32;
export const MAX_MODEL_LIST_BYTES = 2 ** 26;
/** The most bytes a `models` frame of `frameBytes` bytes may decompress to (10.0). */
export function maxModelListBytes(frameBytes) {
  return Math.min(MAX_MODEL_LIST_BYTES, Math.max(MODEL_LIST_FLOOR, MODEL_LIST_RATIO * frameBytes));
}
// Window_Size of a `models` frame (RFC 8878 3.1.1.1.2): the reference's zstd refuses frames that need a
// window above 2^27 (libzstd's default limit); the spec names none (see web/README.md). A frame is decoded
// with a window of at most max(content limit, 128 KiB) whatever it declares, since no back-reference
// within a frame whose content stays inside the limit reaches further.
export const MAX_ZSTD_WINDOW = 2 ** 27;
export const ZSTD_BLOCK_MAX = 2 ** 17;

// --- spatial tiles (format 1.5, spec 10.14) -------------------------------------------------------------

// Tiles of one file: 2 .. 8192. A tile brings up to seven chunks and a file holds at most 65,535 (spec 7).
export const MIN_TILES = 2;
export const MAX_TILES = 8192;
// Tiles one tile's side-information views may draw beside its own (a tile map's `drawn`, format 1.7, spec
// 10.14): at most 64, each another tile of the file, none twice.
export const MAX_DRAWN_TILES = 64;
// Tiles one tile's side information may serve together (a tile map's `span`, format 1.9, spec 10.17): the
// tiles k .. k + span - 1, 1 <= span <= min(64, T - k).
export const MAX_SPAN_TILES = 64;
// What decoding tile k may spend, P_k its attribute payload bytes and P all tiles': table entries
// max(floor(2^25 P_k / P), 16 P_k) and decompressed model-list bytes max(floor(2^23 P_k / P), 32 P_k). The
// floors of one file are shared by its tiles in proportion to their bytes: without the share, a file of
// many tiny tiles would bring one floor per tile, yet each tile can be decoded, and bounded, alone.
export const FILE_TABLE_FLOOR = 2 ** 25;
export const FILE_MODEL_FLOOR = 2 ** 23;
/** floor(floor * tileBytes / fileBytes) exactly (the product passes 2^53 for tiles above 256 MiB). */
function share(floor, tileBytes, fileBytes) {
  return Number((BigInt(floor) * BigInt(tileBytes)) / BigInt(Math.max(fileBytes, 1)));
}
/** The probability-table entries the ECMs of a tile of `tileBytes` attribute bytes may build together. */
export function tileTableEntries(tileBytes, fileBytes) {
  return Math.max(share(FILE_TABLE_FLOOR, tileBytes, fileBytes), MODEL_ENTRIES_PER_BYTE * tileBytes);
}
/** The bytes the `models` frames of a tile of `tileBytes` attribute bytes may decompress to together. */
export function tileModelBytes(tileBytes, fileBytes) {
  return Math.max(share(FILE_MODEL_FLOOR, tileBytes, fileBytes), MODEL_LIST_RATIO * tileBytes);
}

// --- side information (spec 10.7-10.10) -------------------------------------------------------------------

// Views of a SIDE chunk (10.9): 1 .. 2^20.
export const MAX_VIEWS = 2 ** 20;
// Camera width and height (10.8, 10.9): 1 .. 65536, far beyond any sensor.
export const MAX_CAMERA_SIDE = 65536;
// Pixels of one view (10.8): the decoder renders and keeps a target per view; 4096 x 4096.
export const MAX_VIEW_PIXELS = 2 ** 24;
// Pixels of all views together (10.8): at most min(2^28, max(2^22, 1024 x file bytes)). A view without a
// residual costs 52 bytes of SIDE, so without the per-byte rule a 1 KB file could ask for 2^28 pixels; the
// floor admits 24 views of 400 x 400 in any file.
export const MAX_TOTAL_PIXELS = 2 ** 28;
export const PIXEL_FLOOR = 2 ** 22;
export const PIXELS_PER_FILE_BYTE = 1024;
/** The most pixels a file of `fileSize` bytes may ask the decoder to render over all views (10.8). */
export function viewPixelBudget(fileSize) {
  return Math.min(MAX_TOTAL_PIXELS, Math.max(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE * fileSize));
}
// Side information per tile (format 1.6, spec 10.15): the pixel limit of 10.8 holds per tile, the floor
// shared among the tiles in proportion to their bytes Q_k (tile k's attribute and TSID payloads) of Q (all
// tiles'), as 10.14 shares the model floors: min(2^28, max(floor(2^22 Q_k / Q), 1024 Q_k)). Without the
// share, a file of many tiny tiles would bring one 2^22-pixel floor per tile. A span (format 1.9, 10.17) has
// one share: Q_k holds the attribute bytes of all its tiles and its first tile's TSID.
/** The most pixels the views of a tile of `tileBytes` (Q_k) of `allBytes` (Q) may ask for together (10.15). */
export function tileViewPixelBudget(tileBytes, allBytes) {
  return Math.min(MAX_TOTAL_PIXELS, Math.max(share(PIXEL_FLOOR, tileBytes, allBytes), PIXELS_PER_FILE_BYTE * tileBytes));
}
// Residual scale s (10.7, 10.9): 1 .. 16; beyond, a residual of a 4096-pixel view has too few pixels.
export const MAX_RESIDUAL_SCALE = 16;
// Residual gain (10.7): a binary32 that is finite and > 0 once rounded, 2^-150 < gain < 2^128 - 2^103.
export const MIN_GAIN_EXCLUSIVE = 2 ** -150;
export const MAX_GAIN_EXCLUSIVE = 2 ** 128 - 2 ** 103;
// side_info.refine_iterations (10.8): 0 .. 100,000 (default 300); a decoder's default refinement runs at
// most max(1000, N) of them.
export const MAX_REFINE_ITERATIONS = 100000;
export const DEFAULT_REFINE_ITERATIONS = 300;
export const REFINE_DEFAULT_FLOOR = 1000;
// side_info.restorer (10.8): a name of 1 .. 200 characters.
export const MAX_RESTORER_NAME = 200;
