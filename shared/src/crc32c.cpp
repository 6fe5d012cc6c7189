#include "slproto/crc32c.hpp"

#include <array>
#include <cstring>

#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>
#include <nmmintrin.h>
#define SLPROTO_CRC32C_X86 1
#endif
#if defined(__aarch64__)
#include <arm_acle.h>
#include <sys/auxv.h>
#ifndef HWCAP_CRC32
#define HWCAP_CRC32 (1 << 7)
#endif
#define SLPROTO_CRC32C_ARM64 1
#endif

namespace slproto {
namespace {

constexpr std::uint32_t polynomial = 0x82F63B78u;  // reflected Castagnoli

using Tables = std::array<std::array<std::uint32_t, 256>, 8>;

constexpr Tables make_tables() {
  Tables tables{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t crc = i;
    for (int bit = 0; bit < 8; ++bit) crc = (crc & 1u) ? (crc >> 1) ^ polynomial : crc >> 1;
    tables[0][i] = crc;
  }
  for (std::uint32_t i = 0; i < 256; ++i) {
    for (std::size_t t = 1; t < 8; ++t) tables[t][i] = (tables[t - 1][i] >> 8) ^ tables[0][tables[t - 1][i] & 0xFFu];
  }
  return tables;
}

constexpr Tables tables = make_tables();

std::uint32_t slicing_by_8(const unsigned char* p, std::size_t n, std::uint32_t crc) noexcept {
  crc = ~crc;
  while (n >= 8) {
    std::uint32_t low = 0;
    std::uint32_t high = 0;
    std::memcpy(&low, p, 4);
    std::memcpy(&high, p + 4, 4);
#if __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    low = __builtin_bswap32(low);
    high = __builtin_bswap32(high);
#endif
    low ^= crc;
    crc = tables[7][low & 0xFF] ^ tables[6][(low >> 8) & 0xFF] ^ tables[5][(low >> 16) & 0xFF] ^ tables[4][low >> 24] ^
          tables[3][high & 0xFF] ^ tables[2][(high >> 8) & 0xFF] ^ tables[1][(high >> 16) & 0xFF] ^
          tables[0][high >> 24];
    p += 8;
    n -= 8;
  }
  while (n-- > 0) crc = (crc >> 8) ^ tables[0][(crc ^ *p++) & 0xFFu];
  return ~crc;
}

#if defined(SLPROTO_CRC32C_X86)
// All hardware helpers work on the raw CRC register (not inverted); the public functions
// invert on entry and exit.
__attribute__((target("sse4.2"))) std::uint32_t hw_single(const unsigned char* p, std::size_t n,
                                                          std::uint32_t state) noexcept {
  std::uint64_t c = state;
  while (n >= 8) {
    std::uint64_t word = 0;
    std::memcpy(&word, p, 8);
    c = _mm_crc32_u64(c, word);
    p += 8;
    n -= 8;
  }
  auto c32 = static_cast<std::uint32_t>(c);
  while (n-- > 0) c32 = _mm_crc32_u8(c32, *p++);
  return c32;
}

// Linear operator (over GF(2)) that advances a raw CRC register over a fixed number of zero
// bytes, stored as 4 byte-tables so applying it costs 4 lookups.
struct ShiftOperator {
  std::array<std::array<std::uint32_t, 256>, 4> table{};
};

using Matrix = std::array<std::uint32_t, 32>;  // column i = image of bit i

std::uint32_t gf2_times(const Matrix& matrix, std::uint32_t vec) noexcept {
  std::uint32_t sum = 0;
  for (std::size_t i = 0; vec != 0; ++i, vec >>= 1)
    if (vec & 1u) sum ^= matrix[i];
  return sum;
}

ShiftOperator make_shift(std::size_t zero_bytes) {
  Matrix op{};  // one zero bit: s -> (s >> 1) ^ (s & 1 ? P : 0)
  op[0] = polynomial;
  for (std::size_t i = 1; i < 32; ++i) op[i] = 1u << (i - 1);
  Matrix result{};
  for (std::size_t i = 0; i < 32; ++i) result[i] = 1u << i;
  for (std::size_t bits = zero_bytes * 8; bits != 0; bits >>= 1) {
    if (bits & 1u) {
      Matrix next{};
      for (std::size_t i = 0; i < 32; ++i) next[i] = gf2_times(op, result[i]);
      result = next;
    }
    Matrix squared{};
    for (std::size_t i = 0; i < 32; ++i) squared[i] = gf2_times(op, op[i]);
    op = squared;
  }
  ShiftOperator shift;
  for (std::size_t byte = 0; byte < 4; ++byte)
    for (std::uint32_t v = 0; v < 256; ++v) shift.table[byte][v] = gf2_times(result, v << (8 * byte));
  return shift;
}

// One chain of crc32 instructions is latency-bound (3 cycles per 8 bytes); three chains over
// adjacent blocks run at the instruction's throughput, and since the raw CRC is linear,
// crc(s, A ++ B) = shift_|B|(crc(s, A)) ^ crc(0, B) merges them.
constexpr std::size_t block_bytes = 2048;

const ShiftOperator& block_shift() {
  static const ShiftOperator shift = make_shift(block_bytes);
  return shift;
}

std::uint32_t apply(const ShiftOperator& shift, std::uint32_t crc) noexcept {
  return shift.table[0][crc & 0xFF] ^ shift.table[1][(crc >> 8) & 0xFF] ^ shift.table[2][(crc >> 16) & 0xFF] ^
         shift.table[3][crc >> 24];
}

__attribute__((target("sse4.2"))) std::uint32_t hw_interleaved(const unsigned char* p, std::size_t n,
                                                               std::uint32_t state) noexcept {
  if (n >= 3 * block_bytes) {
    const ShiftOperator& shift = block_shift();
    while (n >= 3 * block_bytes) {
      std::uint64_t a = state;
      std::uint64_t b = 0;
      std::uint64_t c = 0;
      for (std::size_t i = 0; i < block_bytes; i += 8) {
        std::uint64_t wa = 0;
        std::uint64_t wb = 0;
        std::uint64_t wc = 0;
        std::memcpy(&wa, p + i, 8);
        std::memcpy(&wb, p + block_bytes + i, 8);
        std::memcpy(&wc, p + 2 * block_bytes + i, 8);
        a = _mm_crc32_u64(a, wa);
        b = _mm_crc32_u64(b, wb);
        c = _mm_crc32_u64(c, wc);
      }
      state = apply(shift, apply(shift, static_cast<std::uint32_t>(a)) ^ static_cast<std::uint32_t>(b)) ^
              static_cast<std::uint32_t>(c);
      p += 3 * block_bytes;
      n -= 3 * block_bytes;
    }
  }
  return hw_single(p, n, state);
}

bool cpu_has_sse42() noexcept {
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (__get_cpuid(1, &eax, &ebx, &ecx, &edx) == 0) return false;
  return (ecx & bit_SSE4_2) != 0;
}
#endif

#if defined(SLPROTO_CRC32C_ARM64)
// ARMv8 CRC32 extension (Cortex-A53/A72 and later boards): crc32cx consumes 8 bytes; its
// latency is low enough on these cores that one chain is well past memory speed there.
__attribute__((target("+crc"))) std::uint32_t arm_crc(const unsigned char* p, std::size_t n,
                                                      std::uint32_t state) noexcept {
  while (n >= 8) {
    std::uint64_t word = 0;
    std::memcpy(&word, p, 8);
    state = __crc32cd(state, word);
    p += 8;
    n -= 8;
  }
  while (n-- > 0) state = __crc32cb(state, *p++);
  return state;
}

bool cpu_has_arm_crc() noexcept { return (getauxval(AT_HWCAP) & HWCAP_CRC32) != 0; }
#endif

}  // namespace

std::uint32_t crc32c_portable(const void* data, std::size_t size, std::uint32_t crc) noexcept {
  return slicing_by_8(static_cast<const unsigned char*>(data), size, crc);
}

bool crc32c_hardware_accelerated() noexcept {
#if defined(SLPROTO_CRC32C_X86)
  static const bool has = cpu_has_sse42();
  return has;
#elif defined(SLPROTO_CRC32C_ARM64)
  static const bool has = cpu_has_arm_crc();
  return has;
#else
  return false;
#endif
}

std::uint32_t crc32c(const void* data, std::size_t size, std::uint32_t crc) noexcept {
  if (size == 0) return crc;
#if defined(SLPROTO_CRC32C_X86)
  if (crc32c_hardware_accelerated()) {
    const auto* p = static_cast<const unsigned char*>(data);
    return ~hw_interleaved(p, size, ~crc);
  }
#elif defined(SLPROTO_CRC32C_ARM64)
  if (crc32c_hardware_accelerated()) return ~arm_crc(static_cast<const unsigned char*>(data), size, ~crc);
#endif
  return crc32c_portable(data, size, crc);
}

std::uint32_t crc32c(std::span<const std::byte> data, std::uint32_t crc) noexcept {
  return crc32c(data.data(), data.size(), crc);
}

}  // namespace slproto
