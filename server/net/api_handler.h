// ApiHandler: what the app plugs into the server for everything under /api and /metrics
// (docs/api.md). The net layer does the HTTP: it reads and limits the request, checks the
// credentials (except for GET /api/health), hands the handler a parsed HttpRequest, and writes
// whatever HttpResponse the handler answers with — from any thread, whenever it is ready, so that
// slow work (slab inserts, dataset builds) runs on the handler's own threads while the I/O threads
// go on serving others.
//
// Bodies: a request whose body the handler asks to stream (BodyModeFor → kStreamed; slab
// uploads) gets a BodyReader and is limited to ServerOptions::max_upload_bytes; any other body
// is read into HttpRequest::body first, at most ServerOptions::max_json_body_bytes (413 beyond).
//
// Thread safety: BodyModeFor and Handle run on an I/O thread (the connection's strand) and must
// not block; HttpResponder and BodyReader may be used from any thread.
#ifndef OCTOSCOPE_NET_API_HANDLER_H_
#define OCTOSCOPE_NET_API_HANDLER_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "net/principal.h"
#include "util/result.h"

namespace octoscope::net {

struct HttpHeader {
  std::string name;
  std::string value;
};

class BodyReader;

struct HttpRequest {
  std::string method;  // "GET", "PUT", ... as sent.
  std::string path;    // Percent-decoded, without the query ("/api/datasets/ab12/slabs").
  // Raw (still encoded), without '?' and without the "token", "share" and "view" parameters.
  std::string query;
  std::vector<HttpHeader> headers;          // As received, without Authorization.
  std::string body;                         // The whole body (BodyMode::kBuffered); else empty.
  std::shared_ptr<BodyReader> body_reader;  // Set for BodyMode::kStreamed, else null.
  // The peer, "127.0.0.1:54321"; behind a trusted proxy the client's address from
  // X-Forwarded-For ("203.0.113.7", no port).
  std::string remote;
  // "https" when a trusted proxy says so in X-Forwarded-Proto, else "http".
  std::string scheme = "http";
  // Who the request speaks for (the Authenticator's answer). GET /api/health, answered without
  // credentials, has a default Principal: a user with an empty name, not admin.
  Principal principal;

  // The value of the first header named `name` (case-insensitive), or "".
  std::string_view Header(std::string_view name) const;
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "application/json";
  std::string body;
  // Extra headers (Allow, Location, Cache-Control to override the default no-store, ...).
  std::vector<HttpHeader> headers;

  static HttpResponse Json(int status, std::string body);
  // {"error": message} (protocol::HttpErrorJson).
  static HttpResponse Error(int status, std::string_view message);
};

// Completes one request. Copies share one completion: the first Respond wins, later ones are
// ignored, and when the last copy is destroyed without any Respond the client gets a 500 (a
// handler can never leave a connection hanging by forgetting to answer). A response after the
// client went away, or after the net layer answered itself (e.g. 413 during an upload), is
// dropped.
class HttpResponder {
 public:
  // `deliver` takes the response to the connection (the net layer's; tests pass their own).
  explicit HttpResponder(std::function<void(HttpResponse)> deliver);

  void Respond(HttpResponse response) const;
  bool responded() const;

 private:
  struct State {
    ~State();
    std::mutex mu;
    bool responded = false;
    std::function<void(HttpResponse)> deliver;
  };
  std::shared_ptr<State> state_;
};

// Pulls a streamed request body piece by piece; the connection reads from the socket only when
// asked, so a slow consumer slows the upload down instead of buffering it.
class BodyReader {
 public:
  // A piece of the body (at most ServerOptions::upload_chunk_bytes); an empty span marks the end
  // of the body. The bytes stay valid until the next Read or until the request is answered.
  // Errors: kResourceExhausted (body over the limit; the client got 413), kInvalidArgument
  // (malformed chunked encoding; 400), kUnavailable (the client went away or stalled, or the
  // server is stopping). After an error the handler's response is ignored.
  using ReadCallback = std::function<void(Result<std::span<const uint8_t>> piece)>;

  virtual ~BodyReader() = default;

  // Starts reading the next piece; `done` runs on an I/O thread (or on the caller's thread when
  // the connection is already gone) and must not block. At most one Read at a time.
  virtual void Read(ReadCallback done) = 0;

  // The body's size from Content-Length; nullopt for chunked uploads.
  virtual std::optional<uint64_t> content_length() const = 0;
};

enum class BodyMode { kBuffered, kStreamed };

class ApiHandler {
 public:
  virtual ~ApiHandler() = default;

  // How to read the body of the request whose header `head` is (its body is not read yet).
  virtual BodyMode BodyModeFor(const HttpRequest& head) {
    (void)head;
    return BodyMode::kBuffered;
  }

  // Answers `request` through `responder`, now or later, from any thread. Exceptions thrown
  // here become a 500.
  virtual void Handle(HttpRequest request, HttpResponder responder) = 0;
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_API_HANDLER_H_
