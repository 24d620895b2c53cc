// A classic CAN frame as a plain value: identifier, flags, payload and receive timestamp.
#pragma once

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <initializer_list>
#include <span>
#include <string>

namespace canbridge::can {

// Classic CAN carries at most 8 bytes. CAN FD (64 bytes) will widen this one constant and
// add FrameFlags::fd; nothing else in the value type assumes 8.
inline constexpr std::size_t kMaxPayload = 8;
inline constexpr std::uint32_t kMaxStandardId = 0x7FF;
inline constexpr std::uint32_t kMaxExtendedId = 0x1FFFFFFF;

struct FrameFlags {
  static constexpr std::uint8_t extended = 0x01;  // 29-bit identifier
  static constexpr std::uint8_t remote = 0x02;    // remote transmission request
  static constexpr std::uint8_t error = 0x04;     // error frame (id holds CAN_ERR_* class bits)
  // Received only: frames of this bus were lost just before this one (the kernel's receive
  // queue overflowed, SO_RXQ_OVFL, or this process's own queue). Receivers that count on frame
  // sequences (PDO Packets) resynchronise at this frame. Never sent, never carried.
  static constexpr std::uint8_t follows_loss = 0x08;
};

struct Frame {
  std::uint32_t id = 0;    // 11-bit or 29-bit identifier, without flag bits
  std::uint8_t len = 0;    // payload length 0..kMaxPayload (for RTR: the requested DLC)
  std::uint8_t flags = 0;  // FrameFlags bits
  std::array<std::uint8_t, kMaxPayload> data{};
  // Receive time (CLOCK_REALTIME since the epoch), from the kernel where the bus has one; zero
  // when unknown or for frames built locally.
  std::chrono::nanoseconds timestamp{0};

  bool is_extended() const { return (flags & FrameFlags::extended) != 0; }
  bool is_remote() const { return (flags & FrameFlags::remote) != 0; }
  bool is_error() const { return (flags & FrameFlags::error) != 0; }
  bool follows_loss() const { return (flags & FrameFlags::follows_loss) != 0; }
  // A standard-id data frame (no extended, remote or error flag; the loss mark does not count).
  bool is_standard_data() const { return (flags & ~FrameFlags::follows_loss) == 0; }
  std::span<const std::uint8_t> payload() const { return {data.data(), is_remote() ? 0u : len}; }

  // A frame of any kind from its parts; the id is masked to 11 or 29 bits by `flags`, bytes
  // beyond kMaxPayload are ignored.
  static Frame make(std::uint32_t id, std::uint8_t flags,
                    std::initializer_list<std::uint8_t> bytes) {
    return from_span(id, std::span<const std::uint8_t>(bytes.begin(), bytes.size()), flags);
  }
  // Standard-id data frame.
  static Frame standard(std::uint32_t id, std::initializer_list<std::uint8_t> bytes) {
    return make(id, 0, bytes);
  }
  static Frame from_span(std::uint32_t id, std::span<const std::uint8_t> bytes,
                         std::uint8_t flags = 0) {
    Frame f;
    f.flags = flags;
    f.id = id & (f.is_extended() ? kMaxExtendedId : kMaxStandardId);
    f.len = static_cast<std::uint8_t>(std::min(bytes.size(), kMaxPayload));
    std::copy_n(bytes.begin(), f.len, f.data.begin());
    return f;
  }
};

// Frames are equal when they would look the same on the wire: timestamps are not compared, and
// payload bytes beyond len (or of a remote frame) do not matter.
inline bool operator==(const Frame& a, const Frame& b) {
  if (a.id != b.id || a.len != b.len || a.flags != b.flags) return false;
  if (a.is_remote()) return true;
  return std::equal(a.data.begin(), a.data.begin() + a.len, b.data.begin());
}

// "123#DEADBEEF" / "12345678#01" / "7FF#R" as cansend writes it (for logs and test messages).
std::string to_string(const Frame& frame);

}  // namespace canbridge::can
