#include "bridge/role_statistics.hpp"

namespace canbridge::bridge {

namespace {
double per_second(std::uint64_t before, std::uint64_t after, double seconds) {
  if (seconds <= 0 || after < before) return 0;
  return static_cast<double>(after - before) / seconds;
}
}  // namespace

std::uint64_t RoleStatistics::drops_total() const {
  std::uint64_t total = 0;
  for (const DropCount& d : drops) total += d.count;
  return total;
}

RoleRates rates_between(const RoleStatistics& before, const RoleStatistics& after,
                        std::chrono::nanoseconds elapsed) {
  RoleRates r;
  r.seconds = std::chrono::duration<double>(elapsed).count();
  if (r.seconds <= 0) r.seconds = 0;
  const double s = r.seconds;
  for (std::size_t i = 0; i < after.buses.size(); ++i) {
    BusRates b;
    if (i < before.buses.size()) {
      b.rx_frames =
          per_second(before.buses[i].counters.rx_frames, after.buses[i].counters.rx_frames, s);
      b.tx_frames =
          per_second(before.buses[i].counters.tx_frames, after.buses[i].counters.tx_frames, s);
    }
    r.buses.push_back(b);
  }
  const BackboneStatistics& x = before.backbone;
  const BackboneStatistics& y = after.backbone;
  r.backbone_tx_bytes = per_second(x.tx_bytes, y.tx_bytes, s);
  r.backbone_rx_bytes = per_second(x.rx_bytes, y.rx_bytes, s);
  r.backbone_frames_sent = per_second(x.frames_sent, y.frames_sent, s);
  r.backbone_frames_received = per_second(x.frames_received, y.frames_received, s);
  if (y.batches_sent > x.batches_sent && y.frames_sent >= x.frames_sent) {
    r.frames_per_message = static_cast<double>(y.frames_sent - x.frames_sent) /
                           static_cast<double>(y.batches_sent - x.batches_sent);
  }
  r.drops = per_second(before.drops_total(), after.drops_total(), s);
  return r;
}

void RateMeter::sample(RoleStatistics snapshot) {
  previous_ = std::move(latest_);
  latest_ = Sample{clock_(), std::move(snapshot)};
}

RoleRates RateMeter::rates() const {
  if (!previous_ || !latest_) {
    RoleRates none;
    if (latest_) none.buses.resize(latest_->snapshot.buses.size());
    return none;
  }
  return rates_between(previous_->snapshot, latest_->snapshot, latest_->at - previous_->at);
}

}  // namespace canbridge::bridge
