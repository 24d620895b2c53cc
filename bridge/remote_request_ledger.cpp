#include "bridge/remote_request_ledger.hpp"

namespace canbridge::bridge {

std::optional<RemoteRequestLedger::End> RemoteRequestLedger::open(
    RequestId id, GatewayId gateway, SessionId session, Effect effect, TimePoint now,
    std::chrono::milliseconds within) {
  if (session == 0) return End::not_sent;
  const TimePoint deadline = now + within;
  requests_[id] = Request{gateway, session, effect, within, deadline, false};
  deadlines_.emplace(deadline, id);
  return std::nullopt;
}

bool RemoteRequestLedger::on_progress(RequestId id, GatewayId from, TimePoint now) {
  const auto it = requests_.find(id);
  if (it == requests_.end() || it->second.gateway != from) return false;
  Request& request = it->second;
  const TimePoint later = now + request.within;
  // Running at the gateway: waiting for its answer again, whatever the surface asked before (a
  // cancel already sent still ends it, and is answered).
  if (later > request.deadline || request.overdue) {
    request.overdue = false;
    move_deadline(id, request, later);
  }
  return true;
}

std::optional<RemoteRequestLedger::End> RemoteRequestLedger::on_result(RequestId id, GatewayId from,
                                                                       Result result) {
  const auto it = requests_.find(id);
  if (it == requests_.end() || it->second.gateway != from) return std::nullopt;
  const Request request = it->second;
  close(id);
  switch (result) {
    case Result::done:
      return End::answered;
    case Result::cancelled_not_started:
      return End::timed_out;  // the surface's cancel: it never ran
    case Result::cancelled_running:
      return unanswered(request);  // stopped halfway: a write may have landed
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
    if (request.overdue) {
      due.ended.push_back({id, unanswered(request)});
      close(id);
      continue;
    }
    // The answer is late: whatever held it (a stalled surface, a cut link), the gateway still
    // holds it and resends it on the next link. The cancel makes sure it never starts late.
    request.overdue = true;
    due.cancels.emplace_back(id, request.gateway);
    move_deadline(id, request, now + options_.resend_window);
  }
  return due;
}

std::vector<RemoteRequestLedger::Ended> RemoteRequestLedger::on_gateway_session(GatewayId gateway,
                                                                                SessionId session) {
  std::vector<Ended> ended;
  if (session == 0) return ended;
  for (const auto& [id, request] : requests_) {
    if (request.gateway == gateway && request.session != session) {
      ended.push_back({id, unanswered(request)});
    }
  }
  for (const Ended& e : ended) close(e.id);
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
  return it != requests_.end() && it->second.overdue;
}

void RemoteRequestLedger::move_deadline(RequestId id, Request& request, TimePoint deadline) {
  deadlines_.erase({request.deadline, id});
  request.deadline = deadline;
  deadlines_.emplace(deadline, id);
}

void RemoteRequestLedger::close(RequestId id) {
  const auto it = requests_.find(id);
  if (it == requests_.end()) return;
  deadlines_.erase({it->second.deadline, id});
  requests_.erase(it);
}

}  // namespace canbridge::bridge
