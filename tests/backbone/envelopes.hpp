// Session envelopes as a scripted peer writes them, matchers for those it expects from the side
// under test, and one-line descriptions of both for failure messages.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "backbone/session.hpp"
#include "session.pb.h"

namespace canbridge::backbone::testing {

// Who a scripted peer pretends to be: what its hellos say.
struct PeerIdentity {
  v1::Hello::Role role = v1::Hello::ROLE_SURFACE;
  std::string name = "scripted";
  std::uint64_t session_id = 0x5C219;
  std::vector<std::uint32_t> module_ids;
  std::string application;  // Hello.application (a gateway's claims)
  std::uint32_t protocol_major = kProtocolMajor;
  std::uint32_t protocol_minor = kProtocolMinor;
};

// The peer's hello. `resume_session_id`: the session of the side under test whose reliable
// stream `ack` acknowledges (0: none); `send_base`: the first seq the peer will send.
inline v1::Envelope hello(const PeerIdentity& peer, std::uint64_t resume_session_id = 0,
                          std::uint64_t ack = 0, std::uint64_t send_base = 1) {
  v1::Envelope e;
  e.set_ack(ack);
  v1::Hello& h = *e.mutable_hello();
  h.set_protocol_major(peer.protocol_major);
  h.set_protocol_minor(peer.protocol_minor);
  h.set_role(peer.role);
  h.set_name(peer.name);
  for (std::uint32_t id : peer.module_ids) h.add_module_ids(id);
  h.set_session_id(peer.session_id);
  h.set_resume_session_id(resume_session_id);
  h.set_send_base(send_base);
  h.add_capabilities("reliable");
  if (!peer.application.empty()) h.set_application(peer.application);
  return e;
}

inline v1::Envelope keepalive(std::uint64_t ack) {
  v1::Envelope e;
  e.set_ack(ack);
  e.mutable_keepalive();
  return e;
}

// Says that everything up to `ack` arrived and `ack + 1` (and each of `missing`) did not.
inline v1::Envelope resend_request(std::uint64_t ack, std::vector<std::uint64_t> missing = {}) {
  v1::Envelope e = keepalive(ack);
  e.set_resend(true);
  for (std::uint64_t m : missing) e.add_missing(m);
  return e;
}

// A reliable payload (seq >= 1) of the peer's stream.
inline v1::Envelope payload(std::uint64_t seq, std::string bytes, std::uint64_t ack = 0) {
  v1::Envelope e;
  e.set_seq(seq);
  e.set_ack(ack);
  e.set_payload(std::move(bytes));
  return e;
}

inline v1::Envelope refusal(v1::Refusal::Reason reason, std::string detail) {
  v1::Envelope e;
  e.mutable_refusal()->set_reason(reason);
  e.mutable_refusal()->set_detail(std::move(detail));
  return e;
}

inline const char* role_text(v1::Hello::Role role) {
  switch (role) {
    case v1::Hello::ROLE_GATEWAY:
      return "gateway";
    case v1::Hello::ROLE_SURFACE:
      return "surface";
    default:
      return "unspecified";
  }
}

// "payload seq 2 ack 1 (8 bytes)", "keepalive ack 3 resend missing [5 7]", ...
inline std::string describe(const v1::Envelope& e) {
  std::string text;
  switch (e.body_case()) {
    case v1::Envelope::kHello: {
      const v1::Hello& h = e.hello();
      text = "hello from " + std::string(role_text(h.role())) + " '" + h.name() + "' (protocol " +
             std::to_string(h.protocol_major()) + "." + std::to_string(h.protocol_minor()) +
             ", session " + std::to_string(h.session_id()) + ", resumes " +
             std::to_string(h.resume_session_id()) + ", send_base " +
             std::to_string(h.send_base()) + ")";
      break;
    }
    case v1::Envelope::kKeepalive:
      text = e.keepalive().hello_please() ? "keepalive asking for a hello" : "keepalive";
      break;
    case v1::Envelope::kRefusal:
      text = "refusal " + v1::Refusal::Reason_Name(e.refusal().reason()) + " (" +
             e.refusal().detail() + ")";
      break;
    case v1::Envelope::kPayload:
      text = e.seq() == 0 ? "unreliable payload" : "payload seq " + std::to_string(e.seq());
      text += " (" + std::to_string(e.payload().size()) + " bytes)";
      break;
    default:
      text = "envelope without a body";
  }
  if (e.ack() != 0) text += " ack " + std::to_string(e.ack());
  if (e.resend()) {
    text += " resend";
    if (e.missing_size() > 0) {
      text += " missing [";
      for (int i = 0; i < e.missing_size(); ++i) {
        text += (i ? " " : "") + std::to_string(e.missing(i));
      }
      text += "]";
    }
  }
  return text;
}

// An expectation on one envelope, with the words a failure names it by.
struct EnvelopeMatch {
  std::string description;
  std::function<bool(const v1::Envelope&)> accepts;
};

inline EnvelopeMatch hello_from(v1::Hello::Role role,
                                std::function<bool(const v1::Hello&)> also = nullptr,
                                std::string also_text = {}) {
  std::string text = "a hello from a " + std::string(role_text(role));
  if (!also_text.empty()) text += " " + also_text;
  return {std::move(text), [role, also = std::move(also)](const v1::Envelope& e) {
            return e.has_hello() && e.hello().role() == role && (!also || also(e.hello()));
          }};
}

// A keepalive (no resend request) acknowledging exactly `ack`.
inline EnvelopeMatch keepalive_acking(std::uint64_t ack) {
  return {"a keepalive acknowledging " + std::to_string(ack), [ack](const v1::Envelope& e) {
            return e.has_keepalive() && !e.keepalive().hello_please() && e.ack() == ack &&
                   !e.resend();
          }};
}

// Any keepalive without a resend request: what an idle side sends, and its bare acks.
inline EnvelopeMatch any_keepalive() {
  return {"a keepalive", [](const v1::Envelope& e) { return e.has_keepalive() && !e.resend(); }};
}

// The reliable payload `seq` with exactly `bytes`.
inline EnvelopeMatch payload_seq(std::uint64_t seq, std::string bytes) {
  return {"payload seq " + std::to_string(seq) + " (" + std::to_string(bytes.size()) + " bytes)",
          [seq, bytes = std::move(bytes)](const v1::Envelope& e) {
            return e.body_case() == v1::Envelope::kPayload && e.seq() == seq &&
                   e.payload() == bytes;
          }};
}

// The reliable payload `seq` emptied: the sender gave it up but keeps the stream contiguous.
inline EnvelopeMatch tombstone_seq(std::uint64_t seq) {
  return payload_seq(seq, {});
}

inline EnvelopeMatch refusal_for(v1::Refusal::Reason reason,
                                 std::vector<std::string> detail_names = {}) {
  std::string text = "a refusal " + v1::Refusal::Reason_Name(reason);
  for (const auto& n : detail_names) text += " naming '" + n + "'";
  return {std::move(text), [reason, names = std::move(detail_names)](const v1::Envelope& e) {
            if (!e.has_refusal() || e.refusal().reason() != reason) return false;
            for (const auto& n : names) {
              if (e.refusal().detail().find(n) == std::string::npos) return false;
            }
            return true;
          }};
}

}  // namespace canbridge::backbone::testing
