// How a decoded integer becomes an attribute value (spec 10.2-10.6): binary64 with correctly rounded
// operations in the order the spec writes them, one rounding to binary32 at the end.

const LN2 = 0.6931471805599453;
const SQRT_HALF = 0.7071067811865476;

// Powers of two 2^-1100 .. 2^1100, built by exact doublings (no reliance on Math.pow's rounding).
const POW2_BIAS = 1100;
const POW2 = (() => {
  const t = new Float64Array(2 * POW2_BIAS + 1);
  t[POW2_BIAS] = 1;
  for (let e = 1; e <= POW2_BIAS; e++) {
    t[POW2_BIAS + e] = t[POW2_BIAS + e - 1] * 2;
    t[POW2_BIAS - e] = t[POW2_BIAS - e + 1] / 2;
  }
  return t;
})();

/** 2^e for an integer e in -1100..1100, exact (0 or Infinity past binary64's range). */
export const pow2 = (e) => POW2[POW2_BIAS + e];

/** The natural logarithm of a positive normal binary64 `x` by the series of spec 10.2. */
export function specLn(x) {
  // x = m 2^e with 0.5 <= m < 1, exactly: estimate e from log2, then correct by exact halvings/doublings.
  let e = Math.floor(Math.log2(x)) + 1;
  let m = x * pow2(-e);
  while (m >= 1) {
    m *= 0.5;
    e += 1;
  }
  while (m < 0.5) {
    m *= 2;
    e -= 1;
  }
  if (m < 0.7071067811865476) {
    m *= 2;
    e -= 1;
  }
  const t = (m - 1) / (m + 1);
  const t2 = t * t;
  let s = 0;
  for (let k = 27; k >= 1; k -= 2) s = s * t2 + 1 / k;
  return 2 * t * s + e * LN2;
}

/** The opacity logit of an opacity integer `q` with `levels` L (spec 10.2), as a binary32 value. */
export function opacityLogit(q, levels) {
  const lo = 0.25 / levels;
  const hi = 1 - 0.25 / levels;
  let a = q / levels;
  if (a < lo) a = lo;
  if (a > hi) a = hi;
  return Math.fround(specLn(a) - specLn(1 - a));
}

/**
 * A function q -> opacityLogit(q, levels): a table over 0..L when L is small (every q outside it clamps to
 * an end), the formula otherwise.
 */
export function opacityDecoder(levels) {
  if (levels > 65536) return (q) => opacityLogit(q, levels);
  const table = new Float32Array(levels + 1);
  for (let q = 0; q <= levels; q++) table[q] = opacityLogit(q, levels);
  return (q) => table[q <= 0 ? 0 : q >= levels ? levels : q];
}

/** Rotation component of integer `q` with `levels` M (spec 10.4), in binary64. */
export function rotationStep(levels) {
  return (2 * SQRT_HALF) / levels;
}

export function rotationComponent(q, step) {
  return q * step - SQRT_HALF;
}

/** The largest component of a unit quaternion whose other three are r1, r2, r3 (binary64). */
export function largestComponent(r1, r2, r3) {
  const rest = 1 - (r1 * r1 + r2 * r2 + r3 * r3);
  return Math.sqrt(rest > 0 ? rest : 0);
}
