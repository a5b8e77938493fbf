// The strict msgpack reader (spec sections 4, 7 and 10.0): what a general-purpose decoder accepts and the
// spec refuses.

import test from 'node:test';
import assert from 'node:assert/strict';
import { MsgpackError, MsgReader, decodeOne, toPlain } from '../src/msgpack.mjs';
import { F64, msgpack } from './writer.mjs';

const bytes = (...b) => Uint8Array.from(b);

test('msgpack: integers stay apart from integral floats, in every width', () => {
  assert.equal(decodeOne(msgpack(300)), 300n);
  assert.equal(decodeOne(msgpack(new F64(300))), 300);
  assert.equal(decodeOne(bytes(0xca, 0x43, 0x96, 0x00, 0x00)), 300); // float 32
  assert.equal(decodeOne(bytes(0xd3, 0, 0, 0, 0, 0, 0, 1, 0x2c)), 300n); // int64 of 300
  assert.equal(decodeOne(bytes(0xcf, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff)), 2n ** 64n - 1n);
  assert.equal(decodeOne(bytes(0xd3, 0x80, 0, 0, 0, 0, 0, 0, 0)), -(2n ** 63n));
  assert.equal(new MsgReader(bytes(0xd0, 0xff)).readIntNumber(), -1);
  assert.throws(() => new MsgReader(msgpack(new F64(2))).readIntNumber(), MsgpackError);
  assert.throws(() => new MsgReader(bytes(0xc3)).readIntNumber(), MsgpackError);
});

test('msgpack: maps have str keys, each once, in order', () => {
  const m = decodeOne(msgpack({ b: 1, a: [true, null, 'x'] }));
  assert.deepEqual([...m.keys()], ['b', 'a']);
  assert.deepEqual(toPlain(m), { b: 1, a: [true, null, 'x'] });
  assert.throws(() => decodeOne(bytes(0x82, 0xa1, 0x61, 1, 0xa1, 0x61, 2)), /'a' appears twice/);
  assert.throws(() => decodeOne(bytes(0x81, 0x01, 0x02)), /key 1/);
  const proto = toPlain(decodeOne(msgpack(new Map([['__proto__', 1]]))));
  assert.equal(Object.getPrototypeOf(proto), Object.prototype);
  assert.equal(Object.getOwnPropertyDescriptor(proto, '__proto__').value, 1);
});

test('msgpack: refused types and bytes', () => {
  assert.throws(() => decodeOne(bytes(0xc1)), /never used/);
  assert.throws(() => decodeOne(bytes(0xd4, 0x05, 0x00)), /extension type 5/);
  assert.throws(() => decodeOne(bytes(0xd6, 0xff, 0, 0, 0, 0)), /extension type -1/); // timestamp 32
  assert.throws(() => decodeOne(bytes(0xc7, 0x01, 0x07, 0x00)), /extension type 7/);
  assert.throws(() => decodeOne(bytes(0xa2, 0xc3, 0x28)), /UTF-8/);
  assert.throws(() => decodeOne(bytes(0xa3, 0xed, 0xa0, 0x80)), /UTF-8/); // a surrogate
  assert.throws(() => decodeOne(bytes(0xc0, 0xc0)), /after/);
  assert.throws(() => decodeOne(bytes(0x92, 0x01)), MsgpackError); // incomplete
});

test('msgpack: counts beyond the bytes left are refused before allocating', () => {
  assert.throws(() => decodeOne(bytes(0xdd, 0xff, 0xff, 0xff, 0xff, 0x00)), /array of 4294967295/);
  assert.throws(() => decodeOne(bytes(0xdf, 0xff, 0xff, 0xff, 0xff, 0x00)), /map of 4294967295/);
  assert.throws(() => decodeOne(bytes(0xc6, 0xff, 0xff, 0xff, 0xf0)), /bin of/);
  assert.throws(() => decodeOne(bytes(0xdb, 0xff, 0xff, 0xff, 0xff)), /str of/);
  assert.throws(() => new MsgReader(bytes(0xdc, 0x00, 0x10, 0x01)).readArrayHeader(), /array of 16/);
});

test('msgpack: nesting stops at 32 levels (the outermost value is level 1)', () => {
  let deep = 0;
  for (let i = 0; i < 32; i++) deep = [deep];
  assert.doesNotThrow(() => decodeOne(msgpack(deep)));
  assert.throws(() => decodeOne(msgpack([deep])), /deeper than 32/);
});
