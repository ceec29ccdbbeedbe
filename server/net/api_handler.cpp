#include "net/api_handler.h"

#include <utility>

#include "protocol/api_json.h"
#include "util/strings.h"

namespace octoscope::net {

std::string_view HttpRequest::Header(std::string_view name) const {
  for (const HttpHeader& h : headers) {
    if (EqualsIgnoreCase(h.name, name)) return h.value;
  }
  return {};
}

HttpResponse HttpResponse::Json(int status, std::string body) {
  HttpResponse r;
  r.status = status;
  r.body = std::move(body);
  return r;
}

HttpResponse HttpResponse::Error(int status, std::string_view message) {
  return Json(status, protocol::HttpErrorJson(message));
}

HttpResponder::HttpResponder(std::function<void(HttpResponse)> deliver)
    : state_(std::make_shared<State>()) {
  state_->deliver = std::move(deliver);
}

void HttpResponder::Respond(HttpResponse response) const {
  std::function<void(HttpResponse)> deliver;
  {
    std::lock_guard<std::mutex> lock(state_->mu);
    if (state_->responded) return;
    state_->responded = true;
    deliver = std::move(state_->deliver);
  }
  if (deliver) deliver(std::move(response));
}

bool HttpResponder::responded() const {
  std::lock_guard<std::mutex> lock(state_->mu);
  return state_->responded;
}

HttpResponder::State::~State() {
  if (responded || !deliver) return;
  try {
    deliver(HttpResponse::Error(500, "the request's handler finished without a response"));
  } catch (...) {
    // A destructor never throws; the connection times out instead.
  }
}

}  // namespace octoscope::net
