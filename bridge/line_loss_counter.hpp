// Counts the process frames the backbone line lost, from the sender's running count of process
// frames sent that each unreliable FrameBatch carries (FrameBatch.process_frames_sent): process
// data is never resent, so what that count skips between two batches the receiver got is lost.
#pragma once

#include <cstddef>
#include <cstdint>

namespace canbridge::bridge {

class LineLossCounter {
 public:
  // One received batch of `frames` frames from the peer process `session_id`, whose running
  // count (this batch included) is `running`; 0: not carried (reliable batches, older peers).
  void on_batch(std::uint64_t session_id, std::uint64_t running, std::size_t frames) {
    if (running == 0) return;
    // The first batch of a peer process sets the baseline: what it sent before we heard from it
    // (another receiver's, a previous link's before this process started) is not ours to count.
    if (session_id == session_id_ && running >= last_ + frames) lost_ += running - last_ - frames;
    session_id_ = session_id;
    last_ = running;
  }
  std::uint64_t lost() const { return lost_; }

 private:
  std::uint64_t session_id_ = 0;
  std::uint64_t last_ = 0;
  std::uint64_t lost_ = 0;
};

}  // namespace canbridge::bridge
