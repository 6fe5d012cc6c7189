// CRC32C (Castagnoli, reflected polynomial 0x82F63B78), as used by iSCSI, ext4 and SSE4.2's
// crc32 instruction. The SSE4.2 (x86-64) or ARMv8 CRC32 (aarch64) path is chosen at run time;
// elsewhere, or without those instructions, a slicing-by-8 table.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

namespace slproto {

// CRC32C of `data` continuing from `crc` (the value returned for the preceding bytes; 0 to
// start). crc32c(b, crc32c(a)) == crc32c(a ++ b).
std::uint32_t crc32c(std::span<const std::byte> data, std::uint32_t crc = 0) noexcept;
std::uint32_t crc32c(const void* data, std::size_t size, std::uint32_t crc = 0) noexcept;

// The portable table implementation, exposed so tests can compare it with the hardware path.
std::uint32_t crc32c_portable(const void* data, std::size_t size, std::uint32_t crc = 0) noexcept;

// True when crc32c() uses the CPU's crc32 instruction.
bool crc32c_hardware_accelerated() noexcept;

}  // namespace slproto
