#include "backbone/admission_control.hpp"

#include <gtest/gtest.h>

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;
using Admission = AdmissionControl::Admission;
using Ids = std::vector<AdmissionControl::ConnectionId>;

const AdmissionControl::Clock::time_point t0{};

AdmissionControl make(std::size_t max_pending, std::size_t max_links) {
  return AdmissionControl({max_pending, 2000ms, max_links});
}

TEST(AdmissionControl, AcceptsUpToTheCapThenEvictsTheOldestPending) {
  auto admission = make(3, 10);
  EXPECT_EQ(admission.on_accepted(1, t0), std::nullopt);
  EXPECT_EQ(admission.on_accepted(2, t0 + 1ms), std::nullopt);
  EXPECT_EQ(admission.on_accepted(3, t0 + 2ms), std::nullopt);
  EXPECT_EQ(admission.on_accepted(4, t0 + 3ms), 1u);
  EXPECT_EQ(admission.on_accepted(5, t0 + 4ms), 2u);
  EXPECT_EQ(admission.pending(), 3u);
  EXPECT_EQ(admission.counters().accepted, 5u);
  EXPECT_EQ(admission.counters().evicted_pending, 2u);
  EXPECT_EQ(admission.counters().pending_peak, 3u);
  // The evicted ones are gone: admitting one now says so.
  EXPECT_EQ(admission.on_admitted(1), Admission::not_pending);
}

TEST(AdmissionControl, SilentConnectionsAreEvictedBeforeOnesWhosePeerSpoke) {
  auto admission = make(3, 10);
  admission.on_accepted(1, t0, true);  // a gateway's hello was there at accept
  admission.on_accepted(2, t0);
  admission.on_accepted(3, t0);
  admission.on_talking(3);  // spoke later
  EXPECT_EQ(admission.on_accepted(4, t0), 2u);
  EXPECT_EQ(admission.on_accepted(5, t0), 4u);
  EXPECT_EQ(admission.on_accepted(6, t0), 5u);
  EXPECT_EQ(admission.counters().evicted_talking, 0u);
  admission.on_talking(6);
  // Every pending one spoke: the oldest goes.
  EXPECT_EQ(admission.on_accepted(7, t0, true), 1u);
  EXPECT_EQ(admission.counters().evicted_talking, 1u);
  EXPECT_EQ(admission.counters().evicted_pending, 4u);
}

TEST(AdmissionControl, AdmittedConnectionsLeaveThePendingCapAndAreNeverEvicted) {
  auto admission = make(2, 10);
  admission.on_accepted(1, t0);
  EXPECT_EQ(admission.on_admitted(1), Admission::admitted);
  EXPECT_EQ(admission.on_admitted(1), Admission::admitted);  // again: no change
  admission.on_accepted(2, t0 + 1ms);
  admission.on_accepted(3, t0 + 2ms);
  EXPECT_EQ(admission.on_accepted(4, t0 + 3ms), 2u);  // not 1: it is admitted
  EXPECT_EQ(admission.admitted(), 1u);
  EXPECT_EQ(admission.counters().admitted, 1u);
}

TEST(AdmissionControl, PendingPastTheTimeoutExpireOldestFirstAndAdmittedNever) {
  auto admission = make(10, 10);
  admission.on_accepted(1, t0);
  admission.on_accepted(2, t0 + 500ms);
  admission.on_accepted(3, t0 + 1000ms);
  EXPECT_EQ(admission.on_admitted(2), Admission::admitted);
  EXPECT_EQ(admission.next_deadline(), t0 + 2000ms);
  EXPECT_EQ(admission.expired(t0 + 1999ms), Ids{});
  EXPECT_EQ(admission.expired(t0 + 2000ms), Ids{1});
  EXPECT_EQ(admission.next_deadline(), t0 + 3000ms);
  EXPECT_EQ(admission.expired(t0 + 10s), Ids{3});
  EXPECT_EQ(admission.next_deadline(), std::nullopt);
  EXPECT_EQ(admission.counters().handshake_timeouts, 2u);
  EXPECT_EQ(admission.admitted(), 1u);
  EXPECT_EQ(admission.on_admitted(3), Admission::not_pending);
}

TEST(AdmissionControl, LinksBeyondMaxLinksAreRefusedUntilOneCloses) {
  auto admission = make(10, 2);
  for (AdmissionControl::ConnectionId id = 1; id <= 4; ++id) admission.on_accepted(id, t0);
  EXPECT_EQ(admission.on_admitted(1), Admission::admitted);
  EXPECT_EQ(admission.on_admitted(2), Admission::admitted);
  EXPECT_EQ(admission.on_admitted(3), Admission::refused);
  EXPECT_EQ(admission.counters().refused_link_cap, 1u);
  EXPECT_EQ(admission.pending(), 1u);  // 3 is no longer tracked: the caller closes it
  admission.on_closed(1, t0);
  EXPECT_EQ(admission.on_admitted(4), Admission::admitted);
  EXPECT_EQ(admission.admitted(), 2u);
}

TEST(AdmissionControl, ClosedConnectionsFreeTheirPlaceAndUnknownIdsAreIgnored) {
  auto admission = make(2, 10);
  admission.on_accepted(1, t0);
  admission.on_accepted(2, t0);
  admission.on_closed(1, t0);
  admission.on_closed(99, t0);
  EXPECT_EQ(admission.on_accepted(3, t0), std::nullopt);  // room again: nothing evicted
  EXPECT_EQ(admission.pending(), 2u);
  EXPECT_EQ(admission.expired(t0 + 2s), (Ids{2, 3}));
  EXPECT_EQ(admission.pending(), 0u);
}

TEST(AdmissionControl, ACapOfZeroStillLetsOneHandshakeRun) {
  auto admission = make(0, 10);
  EXPECT_EQ(admission.on_accepted(1, t0), std::nullopt);
  EXPECT_EQ(admission.on_accepted(2, t0), 1u);
}

TEST(AdmissionControl, UnlimitedNeverEvictsNorExpires) {
  AdmissionControl admission(AdmissionLimits::unlimited());
  for (AdmissionControl::ConnectionId id = 1; id <= 1000; ++id) {
    ASSERT_EQ(admission.on_accepted(id, t0), std::nullopt);
  }
  EXPECT_EQ(admission.expired(t0 + std::chrono::hours(24 * 365)), Ids{});
  EXPECT_EQ(admission.on_admitted(1000), Admission::admitted);
}

TEST(AdmissionControl, AFailingSourceIsRefusedAtAcceptAndCannotEvictAnotherSourcesHandshake) {
  AdmissionLimits limits{4, 2000ms, 10, {2, 500ms, 1024}};
  AdmissionControl admission(limits);
  EXPECT_EQ(admission.on_accepted_from("gateway", 1, t0, true).evicted, std::nullopt);
  // The flood holds its budget of pending slots; beyond it, it is refused, evicting no one.
  EXPECT_FALSE(admission.on_accepted_from("flood", 2, t0, true).refused);
  EXPECT_FALSE(admission.on_accepted_from("flood", 3, t0, true).refused);
  for (AdmissionControl::ConnectionId id = 4; id < 100; ++id) {
    const auto accepted = admission.on_accepted_from("flood", id, t0 + 1ms, true);
    EXPECT_TRUE(accepted.refused);
    EXPECT_EQ(accepted.evicted, std::nullopt);
  }
  EXPECT_TRUE(admission.is_pending(1));
  EXPECT_EQ(admission.pending(), 3u);
  // The flood's handshakes fail; its failures keep it out until they are forgiven.
  admission.on_closed(2, t0 + 10ms);
  admission.on_closed(3, t0 + 10ms);
  EXPECT_TRUE(admission.on_accepted_from("flood", 100, t0 + 20ms).refused);
  EXPECT_FALSE(admission.on_accepted_from("flood", 101, t0 + 510ms).refused);
  // Timed out or evicted pending connections are failures of their source too.
  EXPECT_EQ(admission.expired(t0 + 2510ms), (Ids{1, 101}));
  // One failure outstanding of a budget of 2: one more pending, then refused again.
  EXPECT_FALSE(admission.on_accepted_from("flood", 102, t0 + 2510ms).refused);
  EXPECT_TRUE(admission.on_accepted_from("flood", 103, t0 + 2510ms).refused);
  EXPECT_EQ(admission.on_admitted(1), Admission::not_pending);
  EXPECT_EQ(admission.counters().per_source.refused, 98u);
  EXPECT_EQ(admission.counters().per_source.failures, 4u);
}

TEST(AdmissionControl, AnAdmittedConnectionPutsItsSourceInGoodStanding) {
  AdmissionControl admission({4, 2000ms, 10, {1, 10s, 1024}});
  ASSERT_FALSE(admission.on_accepted_from("gateway", 1, t0).refused);
  EXPECT_TRUE(admission.on_accepted_from("gateway", 2, t0).refused);  // one at a time
  EXPECT_EQ(admission.on_admitted(1), Admission::admitted);
  EXPECT_FALSE(admission.on_accepted_from("gateway", 3, t0).refused);
}

TEST(AdmissionControl, AConnectionWhoseHandshakeCompletedIsNoFailureOfItsSourceWhenLeftUnbound) {
  // A configured gateway's hello refused for its claims, again and again (system.surface_policy):
  // its host must still be let in, for the real gateway behind the same address.
  AdmissionControl admission({4, 2000ms, 10, {1, 10s, 1024}});
  for (AdmissionControl::ConnectionId id = 1; id <= 5; ++id) {
    ASSERT_FALSE(admission.on_accepted_from("host", id, t0, true).refused) << id;
    admission.on_upgraded(id, t0);
    admission.on_closed(id, t0);
  }
  // Nor does a proven one, left pending, hold its source's budget.
  ASSERT_FALSE(admission.on_accepted_from("host", 10, t0, true).refused);
  admission.on_upgraded(10, t0);
  ASSERT_FALSE(admission.on_accepted_from("host", 6, t0, true).refused);
  admission.on_closed(6, t0);  // this one failed before its handshake completed
  EXPECT_TRUE(admission.on_accepted_from("host", 7, t0, true).refused);
  EXPECT_EQ(admission.counters().per_source.failures, 1u);
  // Bound after all: the source is in good standing again.
  EXPECT_EQ(admission.on_admitted(10), Admission::admitted);
  EXPECT_FALSE(admission.on_accepted_from("host", 8, t0, true).refused);
}

}  // namespace
}  // namespace canbridge::backbone
