#pragma once
// FNV-1a hashes: 64-bit for checksums, 128-bit for content keys (the shader cache). Not cryptographic:
// they tell apart honest inputs, they do not resist an adversary.

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace haze::gpu {

inline constexpr uint64_t kFnv64Basis = 0xcbf29ce484222325ull;
inline constexpr uint64_t kFnv64Prime = 0x100000001b3ull;

// FNV-1a 64, continued from h (kFnv64Basis to start) over n bytes.
inline uint64_t fnv1a64(uint64_t h, const void* data, size_t n) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= kFnv64Prime;
  }
  return h;
}

// A 128-bit value as two 64-bit halves.
struct Digest128 {
  uint64_t hi = 0, lo = 0;
  bool operator==(const Digest128&) const = default;
  std::string hex() const {  // 32 lower-case hex digits, hi first
    static constexpr char kDigits[] = "0123456789abcdef";
    std::string s(32, '0');
    for (int i = 0; i < 16; ++i) {
      s[15 - i] = kDigits[(hi >> (4 * i)) & 15];
      s[31 - i] = kDigits[(lo >> (4 * i)) & 15];
    }
    return s;
  }
};

// FNV-1a 128 offset basis 0x6c62272e07bb014262b821756295c58d; prime 2^88 + 0x13b.
inline constexpr Digest128 kFnv128Basis{0x6c62272e07bb0142ull, 0x62b821756295c58dull};

// FNV-1a 128, continued from h (kFnv128Basis to start) over n bytes. The product with the prime is
// h * 0x13b + (h << 88) mod 2^128, in 64-bit arithmetic.
inline Digest128 fnv1a128(Digest128 h, const void* data, size_t n) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < n; ++i) {
    h.lo ^= p[i];
    const uint64_t lo_lo = (h.lo & 0xffffffffull) * 0x13b, lo_hi = (h.lo >> 32) * 0x13b;
    const uint64_t carry = (lo_hi + (lo_lo >> 32)) >> 32;  // high 64 bits of h.lo * 0x13b
    h.hi = h.hi * 0x13b + carry + (h.lo << 24);
    h.lo *= 0x13b;
  }
  return h;
}

// Builds a 128-bit digest from a sequence of fields. Each field is length-prefixed, so that ("ab", "c")
// and ("a", "bc") differ.
class Hasher128 {
 public:
  Hasher128& add(std::string_view field) {
    add_u64(field.size());
    h_ = fnv1a128(h_, field.data(), field.size());
    return *this;
  }
  Hasher128& add_u64(uint64_t v) {
    unsigned char b[8];
    for (int i = 0; i < 8; ++i) b[i] = static_cast<unsigned char>(v >> (8 * i));
    h_ = fnv1a128(h_, b, 8);
    return *this;
  }
  Digest128 digest() const { return h_; }

 private:
  Digest128 h_ = kFnv128Basis;
};

}  // namespace haze::gpu
