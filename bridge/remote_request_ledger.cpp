#include "bridge/remote_request_ledger.hpp"

namespace canbridge::bridge {

std::optional<RemoteRequestLedger::End> RemoteRequestLedger::open(
    RequestId id, GatewayId gateway, SessionId session, Effect effect, TimePoint now,
    std::chrono::milliseconds within) {
  RequestLife life;
  if (session == 0) return life.refused();
  life.sent(now, effect, now + within);
  requests_[id] = Request{gateway, session, within, life};
  deadlines_.emplace(life.deadline(), id);
  return std::nullopt;
}

bool RemoteRequestLedger::on_progress(RequestId id, GatewayId from, TimePoint now) {
  const auto it = requests_.find(id);
  if (it == requests_.end() || it->second.gateway != from) return false;
  Request& request = it->second;
  const TimePoint later = now + request.within;
  // Running at the gateway: waiting for its answer again, whatever the surface asked before (a
  // cancel already sent still ends it, and is answered).
  if (later > request.life.deadline() || request.life.awaiting()) {
    move_deadline(id, request, [later](RequestLife& life) { life.running(later); });
  }
  return true;
}

std::optional<RemoteRequestLedger::End> RemoteRequestLedger::on_result(RequestId id, GatewayId from,
                                                                       Result result) {
  const auto it = requests_.find(id);
  if (it == requests_.end() || it->second.gateway != from) return std::nullopt;
  RequestLife life = it->second.life;
  close(id);
  switch (result) {
    case Result::done:
      return End::answered;
    case Result::cancelled_not_started:  // the surface's cancel: it never ran
      return life.end_unanswered(MayHaveRun::no_never_started);
    case Result::cancelled_running:  // stopped halfway: a write may have landed
      return life.end_unanswered(MayHaveRun::yes);
  }
  return End::answered;
}

bool RemoteRequestLedger::cancel(RequestId id) {
  if (!requests_.contains(id)) return false;
  close(id);
  return true;
}

RemoteRequestLedger::Due RemoteRequestLedger::on_time(TimePoint now) {
  Due due;
  while (!deadlines_.empty() && deadlines_.begin()->first <= now) {
    const RequestId id = deadlines_.begin()->second;
    Request& request = requests_.at(id);
    if (request.life.awaiting()) {
      RequestLife life = request.life;
      close(id);
      due.ended.push_back({id, life.end_unanswered(MayHaveRun::yes)});
      continue;
    }
    // The answer is late: whatever held it (a stalled surface, a cut link), the gateway still
    // holds it and resends it on the next link. The cancel makes sure it never starts late.
    due.cancels.emplace_back(id, request.gateway);
    const TimePoint window_end = now + options_.resend_window;
    move_deadline(id, request, [window_end](RequestLife& life) { life.await_answer(window_end); });
  }
  return due;
}

std::vector<RemoteRequestLedger::Ended> RemoteRequestLedger::on_gateway_session(GatewayId gateway,
                                                                                SessionId session) {
  std::vector<Ended> ended;
  if (session == 0) return ended;
  std::vector<std::pair<RequestId, RequestLife>> gone;
  for (const auto& [id, request] : requests_) {
    if (request.gateway == gateway && request.session != session)
      gone.emplace_back(id, request.life);
  }
  for (auto& [id, life] : gone) {
    close(id);  // by its deadline, before the end moves it
    ended.push_back({id, life.end_unanswered(MayHaveRun::yes)});
  }
  return ended;
}

std::optional<RemoteRequestLedger::TimePoint> RemoteRequestLedger::next_deadline() const {
  if (deadlines_.empty()) return std::nullopt;
  return deadlines_.begin()->first;
}

std::optional<RemoteRequestLedger::GatewayId> RemoteRequestLedger::gateway_of(RequestId id) const {
  const auto it = requests_.find(id);
  if (it == requests_.end()) return std::nullopt;
  return it->second.gateway;
}

bool RemoteRequestLedger::overdue(RequestId id) const {
  const auto it = requests_.find(id);
  return it != requests_.end() && it->second.life.awaiting();
}

void RemoteRequestLedger::close(RequestId id) {
  const auto it = requests_.find(id);
  if (it == requests_.end()) return;
  deadlines_.erase({it->second.life.deadline(), id});
  requests_.erase(it);
}

}  // namespace canbridge::bridge
