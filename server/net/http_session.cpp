#include "net/http_session.h"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/http/file_body.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/write.hpp>
#include <boost/beast/websocket/rfc6455.hpp>
#include <cstdio>
#include <exception>
#include <limits>
#include <span>
#include <string_view>
#include <utility>

#include "net/auth.h"
#include "net/static_files.h"
#include "net/websocket_session.h"
#include "protocol/query_string.h"
#include "util/strings.h"

namespace octoscope::net::detail {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

// How long a closing connection keeps draining what the client still sends, and how much.
constexpr std::chrono::seconds kLingerTime{2};
constexpr size_t kMaxLingerBytes = size_t{1} << 20;
constexpr std::string_view kContinue = "HTTP/1.1 100 Continue\r\n\r\n";

// Beast 1.74 uses boost::string_view.
std::string_view Std(beast::string_view s) { return {s.data(), s.size()}; }
beast::string_view Beast(std::string_view s) { return {s.data(), s.size()}; }

// The last item of a comma-separated header value (the proxy nearest to us appends last).
std::string_view LastListItem(std::string_view value) {
  if (const size_t comma = value.rfind(','); comma != std::string_view::npos) {
    value = value.substr(comma + 1);
  }
  return TrimWhitespace(value);
}

bool IsHttpParseError(const beast::error_code& ec) {
  return ec.category() == http::make_error_code(http::error::bad_method).category();
}

std::string Endpoint(const tcp::socket& socket) {
  beast::error_code ec;
  const tcp::endpoint e = socket.remote_endpoint(ec);
  if (ec) return "?";
  return e.address().to_string() + ":" + std::to_string(e.port());
}

asio::ip::address PeerAddress(const tcp::socket& socket) {
  beast::error_code ec;
  const tcp::endpoint e = socket.remote_endpoint(ec);
  return ec ? asio::ip::address() : e.address();
}

// `path` with the segment after any of `prefixes` replaced by "<redacted>" (view-link ids are
// credentials: whoever has one opens the view).
std::string RedactPath(std::string_view path, const std::vector<std::string>& prefixes) {
  for (const std::string& prefix : prefixes) {
    if (prefix.empty() || !path.starts_with(prefix) || path.size() == prefix.size()) continue;
    const size_t end = path.find('/', prefix.size());
    return prefix + "<redacted>" +
           std::string(end == std::string_view::npos ? std::string_view() : path.substr(end));
  }
  return std::string(path);
}

// A header value may not contain line breaks (they would forge headers).
bool SafeHeaderValue(std::string_view value) {
  return value.find_first_of("\r\n") == std::string_view::npos;
}

// The BodyReader of a streamed request: every Read is posted to the connection's strand.
class UploadReader : public BodyReader {
 public:
  UploadReader(std::weak_ptr<HttpSession> session, std::shared_ptr<ServerCore> core,
               uint64_t request_id, std::optional<uint64_t> length)
      : session_(std::move(session)),
        core_(std::move(core)),
        request_id_(request_id),
        length_(length) {}

  void Read(ReadCallback done) override {
    auto callback = std::make_shared<ReadCallback>(std::move(done));
    const bool posted = core_->Post(session_, [id = request_id_, callback](HttpSession& s) {
      s.ReadBodyPiece(id, std::move(*callback));
    });
    if (!posted && *callback) (*callback)(UnavailableError("the connection is closed"));
  }

  std::optional<uint64_t> content_length() const override { return length_; }

 private:
  const std::weak_ptr<HttpSession> session_;
  const std::shared_ptr<ServerCore> core_;
  const uint64_t request_id_;
  const std::optional<uint64_t> length_;
};

}  // namespace

void ApplyCommonHeaders(http::fields& fields) {
  fields.set(http::field::server, "octoscope");
  fields.set("X-Content-Type-Options", "nosniff");
  // Pages are opened with ?token=...: never leak it to another site through Referer.
  fields.set("Referrer-Policy", "no-referrer");
}

HttpSession::HttpSession(tcp::socket socket, std::shared_ptr<ServerCore> core,
                         ConnectionLimits::Slot total, ConnectionLimits::Slot client)
    : core_(std::move(core)),
      stream_(std::move(socket)),
      buffer_(core_->options.max_header_bytes + (size_t{64} << 10)),
      peer_(PeerAddress(stream_.socket())),
      via_proxy_(core_->proxies.Contains(peer_)),
      total_slot_(std::move(total)),
      client_slot_(std::move(client)),
      peer_remote_(Endpoint(stream_.socket())),
      remote_(peer_remote_) {}

HttpSession::~HttpSession() {
  if (piece_done_) FailPiece(UnavailableError("the connection is closed"));
  core_->registry.Remove(registry_id_);
}

void HttpSession::Start() {
  registry_id_ = core_->registry.Add(weak_from_this());
  asio::dispatch(stream_.get_executor(), [self = shared_from_this()] {
    if (self->core_->shutting_down) {
      self->CloseNow();
      return;
    }
    self->DoReadHeader();
  });
}

void HttpSession::BeginShutdown() {
  core_->Post(weak_from_this(), [](HttpSession& s) {
    s.shutting_down_ = true;
    // Between requests nothing is in flight: close now. Otherwise the response closes.
    if (s.state_ == State::kReadingHeader) s.CloseNow();
  });
}

void HttpSession::ForceClose() {
  core_->Post(weak_from_this(), [](HttpSession& s) { s.CloseNow(); });
}

void HttpSession::DoReadHeader() {
  state_ = State::kReadingHeader;
  method_.clear();
  path_.clear();
  query_.clear();
  principal_ = Principal();
  keep_alive_ = false;
  body_complete_ = true;
  expect_continue_ = false;
  force_close_ = false;
  body_parser_.reset();
  upload_parser_.reset();
  pending_.reset();
  deferred_response_.reset();
  piece_.clear();
  piece_.shrink_to_fit();
  if (via_proxy_) client_slot_.reset();  // Idle, the connection speaks for nobody.
  header_parser_.emplace();
  header_parser_->header_limit(static_cast<uint32_t>(core_->options.max_header_bytes));
  // Body limits depend on the route; they are set once the header has been looked at. (Not
  // boost::none: Beast 1.74 compares a Content-Length against it and always fails.)
  header_parser_->body_limit(std::numeric_limits<uint64_t>::max());
  stream_.expires_after(core_->options.read_timeout);
  http::async_read_header(
      stream_, buffer_, *header_parser_,
      [self = shared_from_this()](beast::error_code ec, size_t) { self->OnReadHeader(ec); });
}

void HttpSession::OnReadHeader(beast::error_code ec) {
  if (state_ == State::kClosed) return;
  started_ = std::chrono::steady_clock::now();
  if (ec) {
    if (ec == http::error::header_limit || ec == http::error::buffer_overflow) {
      SendError(431, "request line and headers over " +
                         std::to_string(core_->options.max_header_bytes) + " bytes");
    } else if (IsHttpParseError(ec) && ec != http::error::end_of_stream &&
               header_parser_->got_some()) {
      SendError(400, "malformed HTTP request: " + ec.message());
    } else {
      // The client closed, went silent (timeout), or the socket failed: nothing to answer.
      if (ec == beast::error::timeout && header_parser_->got_some()) {
        core_->Log(LogLevel::kInfo, "HTTP " + remote_ + " request header timed out");
      }
      CloseNow();
    }
    return;
  }
  ++request_id_;
  auto& request = header_parser_->get();
  method_ = std::string(Std(request.method_string()));
  keep_alive_ = request.keep_alive();
  body_complete_ = header_parser_->is_done();
  expect_continue_ =
      !body_complete_ &&
      EqualsIgnoreCase(TrimWhitespace(Std(request[http::field::expect])), "100-continue");
  const std::string_view target = Std(request.target());
  const size_t question = target.find('?');
  const std::string_view raw_path = target.substr(0, question);
  if (question != std::string_view::npos) query_ = std::string(target.substr(question + 1));
  if (raw_path.empty() || raw_path[0] != '/') {
    SendError(400, "the request target must be an absolute path");
    return;
  }
  Result<std::string> path = protocol::PercentDecode(raw_path, false);
  if (!path.ok()) {
    SendError(400, "request path: " + path.status().message());
    return;
  }
  path_ = std::move(path).value();
  IdentifyClient();
  Route();
}

void HttpSession::IdentifyClient() {
  remote_ = peer_remote_;
  scheme_ = "http";
  forwarded_client_.clear();
  if (!via_proxy_) return;
  const auto& request = header_parser_->get();
  forwarded_client_ = core_->proxies.ClientAddress(peer_, Std(request["X-Forwarded-For"]));
  if (!forwarded_client_.empty()) remote_ = forwarded_client_;
  if (EqualsIgnoreCase(LastListItem(Std(request["X-Forwarded-Proto"])), "https")) scheme_ = "https";
}

bool HttpSession::AdmitForwardedClient() {
  // Direct peers took their place at accept; the proxy's own requests count in all only.
  if (!via_proxy_ || forwarded_client_.empty()) return true;
  std::optional<ConnectionLimits::Slot> slot = core_->limits.AcquireAddress(forwarded_client_);
  if (!slot) {
    SendError(503,
              "too many connections from " + forwarded_client_ + " (max-connections-per-address " +
                  std::to_string(core_->limits.max_per_address()) + "); retry later",
              {{"Retry-After", kRetryAfterSeconds}});
    return false;
  }
  client_slot_ = std::move(*slot);
  return true;
}

bool HttpSession::OriginAllowed() {
  const auto& request = header_parser_->get();
  const auto origin = request.find(http::field::origin);
  if (origin == request.end()) return true;  // Not a browser.
  std::optional<WebOrigin> forwarded;
  if (via_proxy_) {
    // The origin the proxy serves: the scheme it says, the host the browser asked it for.
    std::string_view host = LastListItem(Std(request["X-Forwarded-Host"]));
    if (host.empty()) host = TrimWhitespace(Std(request[http::field::host]));
    if (Result<WebOrigin> served = ParseAuthority(scheme_, host); served.ok()) {
      forwarded = std::move(*served);
    }
  }
  const std::string_view value = Std(origin->value());
  if (core_->origins.Allows(value, forwarded)) return true;
  core_->Log(LogLevel::kWarning, "WS " + remote_ + " refused: a page of Origin \"" +
                                     Printable(value, 100) +
                                     "\" may not open WebSockets here (allowed-origins)");
  return false;
}

bool HttpSession::Authenticate() {
  const auto& request = header_parser_->get();
  const std::string_view authorization = Std(request[http::field::authorization]);
  std::optional<Principal> principal;
  std::string refusal = "missing or wrong token";
  const bool ok = core_->CallUser("Authenticator", [&] {
    principal = core_->options.authenticator->Authenticate(authorization, query_);
    if (!principal) refusal = core_->options.authenticator->RefusalMessage(authorization, query_);
  });
  if (!ok) {
    SendError(500, "internal error while checking the credentials");
    return false;
  }
  if (!principal) {
    SendError(401, refusal);
    return false;
  }
  principal_ = std::move(*principal);
  return true;
}

void HttpSession::Route() {
  if (shutting_down_ || core_->shutting_down) {
    SendError(503, "the server is shutting down");
    return;
  }
  if (!AdmitForwardedClient()) return;
  const auto& request = header_parser_->get();
  if (websocket::is_upgrade(request)) {
    if (path_ != "/ws") {
      SendError(404, "no WebSocket endpoint at this path");
    } else if (!OriginAllowed()) {
      SendError(403, "this page's origin may not open WebSockets here");
    } else if (Authenticate()) {
      UpgradeToWebSocket();
    }
    return;
  }
  if (path_ == "/ws") {
    SendError(426, "a WebSocket upgrade is required here", {{"Upgrade", "websocket"}});
    return;
  }
  const bool api = path_ == "/api" || path_.starts_with("/api/") || path_ == "/metrics";
  if (api) {
    const bool health = path_ == "/api/health" && (request.method() == http::verb::get ||
                                                   request.method() == http::verb::head);
    if (!health && !Authenticate()) return;
    StartApi();
    return;
  }
  ServeStatic();
}

void HttpSession::ServeStatic() {
  const auto& request = header_parser_->get();
  const bool head = request.method() == http::verb::head;
  if (request.method() != http::verb::get && !head) {
    SendError(405, "static files accept GET and HEAD", {{"Allow", "GET, HEAD"}});
    return;
  }
  std::optional<StaticFile> file;
  if (!core_->web_root.empty()) file = ResolveStaticFile(core_->web_root, path_);
  if (!file) {
    SendError(404, "no such file");
    return;
  }
  const bool close = MustClose();
  const std::string_view mime = MimeTypeFor(file->path.native());
  auto set_headers = [&](http::fields& fields) {
    ApplyCommonHeaders(fields);
    fields.set(http::field::cache_control, "no-cache");
    fields.set(http::field::etag, file->etag);
  };
  if (EtagMatches(Std(request[http::field::if_none_match]), file->etag)) {
    auto response = std::make_shared<http::response<http::empty_body>>(http::status::not_modified,
                                                                       request.version());
    set_headers(*response);
    response->keep_alive(!close);
    Write(std::move(response), close);
    return;
  }
  beast::error_code ec;
  http::file_body::value_type body;
  body.open(file->path.c_str(), beast::file_mode::scan, ec);
  if (ec) {
    SendError(404, "no such file");
    return;
  }
  if (head) {
    auto response =
        std::make_shared<http::response<http::empty_body>>(http::status::ok, request.version());
    set_headers(*response);
    response->set(http::field::content_type, Beast(mime));
    response->content_length(body.size());
    response->keep_alive(!close);
    Write(std::move(response), close);
    return;
  }
  const uint64_t size = body.size();
  auto response = std::make_shared<http::response<http::file_body>>(
      std::piecewise_construct, std::make_tuple(std::move(body)),
      std::make_tuple(http::status::ok, request.version()));
  set_headers(*response);
  response->set(http::field::content_type, Beast(mime));
  response->content_length(size);
  response->keep_alive(!close);
  Write(std::move(response), close);
}

void HttpSession::StartApi() {
  const auto& request = header_parser_->get();
  HttpRequest r;
  r.method = method_;
  r.path = path_;
  r.query = StripCredentials(query_);
  r.remote = remote_;
  r.scheme = scheme_;
  r.principal = principal_;
  for (const auto& field : request) {
    if (field.name() == http::field::authorization) continue;  // Handlers never see the secret.
    r.headers.push_back({std::string(Std(field.name_string())), std::string(Std(field.value()))});
  }
  BodyMode mode = BodyMode::kBuffered;
  if (!core_->CallUser("ApiHandler::BodyModeFor", [&] { mode = core_->api->BodyModeFor(r); })) {
    SendError(500, "internal error while routing the request");
    return;
  }
  const boost::optional<uint64_t> length = header_parser_->content_length();
  const ServerOptions& options = core_->options;
  if (mode == BodyMode::kStreamed) {
    if (length && *length > options.max_upload_bytes) {
      SendError(413, "body of " + std::to_string(*length) + " bytes over the upload limit of " +
                         std::to_string(options.max_upload_bytes) + " bytes");
      return;
    }
    if (!body_complete_) {
      upload_parser_.emplace(std::move(*header_parser_));
      upload_parser_->body_limit(options.max_upload_bytes);
    }
    header_parser_.reset();
    r.body_reader = std::make_shared<UploadReader>(
        weak_from_this(), core_, request_id_,
        length ? std::optional<uint64_t>(*length) : std::optional<uint64_t>());
    pending_ = std::move(r);
    CallHandler();
    return;
  }
  if (length && *length > options.max_json_body_bytes) {
    SendError(413, "body of " + std::to_string(*length) + " bytes over the limit of " +
                       std::to_string(options.max_json_body_bytes) + " bytes");
    return;
  }
  pending_ = std::move(r);
  if (body_complete_) {
    header_parser_.reset();
    CallHandler();
    return;
  }
  state_ = State::kReadingBody;
  body_parser_.emplace(std::move(*header_parser_));
  header_parser_.reset();
  body_parser_->body_limit(options.max_json_body_bytes);
  ContinueThen([this] {
    stream_.expires_after(core_->options.read_timeout);
    http::async_read(stream_, buffer_, *body_parser_,
                     [self = shared_from_this()](beast::error_code ec, size_t) {
                       self->OnReadBufferedBody(ec);
                     });
  });
}

void HttpSession::OnReadBufferedBody(beast::error_code ec) {
  if (state_ != State::kReadingBody) return;
  if (ec) {
    if (ec == http::error::body_limit) {
      SendError(413, "body over the limit of " +
                         std::to_string(core_->options.max_json_body_bytes) + " bytes");
    } else if (IsHttpParseError(ec) && ec != http::error::partial_message &&
               ec != http::error::end_of_stream) {
      SendError(400, "malformed HTTP body: " + ec.message());
    } else {
      CloseNow();
    }
    return;
  }
  body_complete_ = true;
  pending_->body = body_parser_->release().body();
  body_parser_.reset();
  CallHandler();
}

void HttpSession::CallHandler() {
  state_ = State::kHandling;
  // Nothing else owns the session while the handler works without I/O pending (responders and
  // readers hold weak references); Write and CloseNow release this.
  keep_alive_while_handling_ = shared_from_this();
  HttpRequest request = std::move(*pending_);
  pending_.reset();
  HttpResponder responder(
      [weak = weak_from_this(), core = core_, id = request_id_](HttpResponse response) {
        core->Post(weak, [id, response = std::move(response)](HttpSession& s) mutable {
          s.DeliverResponse(id, std::move(response));
        });
      });
  bool threw = true;
  std::string what;
  try {
    core_->api->Handle(std::move(request), responder);
    threw = false;
  } catch (const std::exception& e) {
    what = e.what();
  } catch (...) {
    what = "a non-standard exception";
  }
  if (threw) {
    core_->Log(LogLevel::kError,
               "ApiHandler::Handle threw on " + method_ + " " + LoggedPath() + ": " + what);
    responder.Respond(HttpResponse::Error(500, "internal error: " + what));
  }
}

void HttpSession::DeliverResponse(uint64_t request_id, HttpResponse response) {
  if (request_id != request_id_ || state_ != State::kHandling) return;  // Stale or answered.
  if (continue_writing_) {
    // "100 Continue" is being written; answer right after it.
    deferred_response_ = std::move(response);
    return;
  }
  if (piece_done_) {
    // Answered while a body piece is being read: stop reading (its callback gets kUnavailable).
    beast::error_code ignored;
    stream_.socket().cancel(ignored);
  }
  SendResponse(std::move(response));
}

void HttpSession::ReadBodyPiece(uint64_t request_id, BodyReader::ReadCallback done) {
  if (request_id != request_id_ || state_ != State::kHandling || !upload_parser_) {
    if (request_id == request_id_ && state_ == State::kHandling && body_complete_ && !piece_done_) {
      // A request without a body: the end at once.
      core_->CallUser("BodyReader callback", [&] { done(std::span<const uint8_t>()); });
      return;
    }
    core_->CallUser("BodyReader callback",
                    [&] { done(UnavailableError("the request's body is no longer being read")); });
    return;
  }
  if (piece_done_) {
    core_->CallUser("BodyReader callback", [&] {
      done(InternalError("BodyReader::Read called while a read is in progress"));
    });
    return;
  }
  piece_done_ = std::move(done);
  if (body_complete_) {
    auto callback = std::move(piece_done_);
    piece_done_ = nullptr;
    core_->CallUser("BodyReader callback", [&] { callback(std::span<const uint8_t>()); });
    return;
  }
  ContinueThen([this] { DoReadPiece(); });
}

void HttpSession::DoReadPiece() {
  if (state_ != State::kHandling) {
    FailPiece(UnavailableError("the request was answered before its body was read"));
    return;
  }
  piece_.resize(core_->options.upload_chunk_bytes);
  auto& body = upload_parser_->get().body();
  body.data = piece_.data();
  body.size = piece_.size();
  body.more = true;
  stream_.expires_after(core_->options.read_timeout);
  http::async_read_some(
      stream_, buffer_, *upload_parser_,
      [self = shared_from_this()](beast::error_code ec, size_t) { self->OnReadPiece(ec); });
}

void HttpSession::OnReadPiece(beast::error_code ec) {
  if (state_ != State::kHandling) {
    FailPiece(UnavailableError("the request was answered before its body was read"));
    return;
  }
  if (ec == http::error::need_buffer) ec = {};
  if (ec) {
    if (ec == http::error::body_limit) {
      const std::string message = "body over the upload limit of " +
                                  std::to_string(core_->options.max_upload_bytes) + " bytes";
      FailPiece(ResourceExhaustedError(message));
      SendError(413, message);
    } else if (ec == beast::error::timeout) {
      core_->Log(LogLevel::kWarning, "HTTP " + remote_ + " " + method_ + " " + LoggedPath() +
                                         ": upload stalled, closing");
      FailPiece(UnavailableError("the upload stalled"));
      CloseNow();
    } else if (IsHttpParseError(ec) && ec != http::error::partial_message &&
               ec != http::error::end_of_stream) {
      const std::string message = "malformed HTTP body: " + ec.message();
      FailPiece(InvalidArgumentError(message));
      SendError(400, message);
    } else {
      core_->Log(LogLevel::kInfo, "HTTP " + remote_ + " " + method_ + " " + LoggedPath() +
                                      ": client went away during the upload");
      FailPiece(UnavailableError("the client went away during the upload: " + ec.message()));
      CloseNow();
    }
    return;
  }
  const size_t bytes = piece_.size() - upload_parser_->get().body().size;
  if (upload_parser_->is_done()) body_complete_ = true;
  if (bytes == 0 && !body_complete_) {
    DoReadPiece();  // Only framing (a chunk header) was parsed.
    return;
  }
  auto callback = std::move(piece_done_);
  piece_done_ = nullptr;
  core_->CallUser("BodyReader callback",
                  [&] { callback(std::span<const uint8_t>(piece_.data(), bytes)); });
}

void HttpSession::FailPiece(Status status) {
  if (!piece_done_) return;
  auto callback = std::move(piece_done_);
  piece_done_ = nullptr;
  core_->CallUser("BodyReader callback", [&] { callback(std::move(status)); });
}

void HttpSession::ContinueThen(std::function<void()> next) {
  if (!expect_continue_) {
    next();
    return;
  }
  expect_continue_ = false;
  continue_writing_ = true;
  stream_.expires_after(core_->options.write_timeout);
  asio::async_write(
      stream_, asio::buffer(kContinue.data(), kContinue.size()),
      [self = shared_from_this(), next = std::move(next)](beast::error_code ec, size_t) {
        self->continue_writing_ = false;
        if (self->state_ == State::kClosed) return;
        if (ec) {
          self->FailPiece(UnavailableError("the client went away"));
          self->CloseNow();
          return;
        }
        if (self->deferred_response_) {
          self->FailPiece(UnavailableError("the request was answered before its body was read"));
          HttpResponse response = std::move(*self->deferred_response_);
          self->deferred_response_.reset();
          self->SendResponse(std::move(response));
          return;
        }
        next();
      });
}

void HttpSession::UpgradeToWebSocket() {
  http::request<http::empty_body> request = header_parser_->release();
  header_parser_.reset();
  WsConnectInfo info;
  info.remote = remote_;
  info.scheme = scheme_;
  info.query = StripCredentials(query_);
  info.principal = std::move(principal_);
  auto session =
      std::make_shared<WebSocketSession>(stream_.release_socket(), core_, std::move(info),
                                         std::move(total_slot_), std::move(client_slot_));
  state_ = State::kClosed;  // This object ends here; the socket lives on in the WebSocket.
  session->Start(std::move(request));
}

std::string HttpSession::LoggedPath() const {
  if (path_.empty()) return "-";
  return Printable(RedactPath(path_, core_->options.secret_path_prefixes), 200);
}

bool HttpSession::MustClose() const {
  return force_close_ || !keep_alive_ || !body_complete_ || shutting_down_ || core_->shutting_down;
}

void HttpSession::SendError(int status, std::string_view message, std::vector<HttpHeader> extra) {
  force_close_ = true;
  HttpResponse response = HttpResponse::Error(status, message);
  response.headers = std::move(extra);
  if (status == 401) response.headers.push_back({"WWW-Authenticate", "Bearer"});
  SendResponse(std::move(response));
}

void HttpSession::SendResponse(HttpResponse r) {
  if (r.status < 100 || r.status > 599) {
    core_->Log(LogLevel::kError, "handler answered " + method_ + " " + LoggedPath() +
                                     " with invalid status " + std::to_string(r.status));
    r = HttpResponse::Error(500, "internal error: invalid response status");
  }
  const bool close = MustClose();
  auto response = std::make_shared<http::response<http::string_body>>();
  response->version(11);
  response->result(static_cast<unsigned>(r.status));
  ApplyCommonHeaders(*response);
  response->set(http::field::cache_control, "no-store");
  if (!r.content_type.empty()) response->set(http::field::content_type, r.content_type);
  for (const HttpHeader& h : r.headers) {
    if (!SafeHeaderValue(h.name) || !SafeHeaderValue(h.value) || h.name.empty()) {
      core_->Log(LogLevel::kError,
                 "dropped a response header with a line break: " + Printable(h.name, 40));
      continue;
    }
    response->set(h.name, h.value);
  }
  response->body() = std::move(r.body);
  response->keep_alive(!close);
  response->prepare_payload();
  Write(std::move(response), close);
}

template <typename Message>
void HttpSession::Write(std::shared_ptr<Message> message, bool close) {
  state_ = State::kWriting;
  const int status = static_cast<int>(message->result_int());
  const uint64_t body_bytes = message->payload_size().value_or(0);
  response_ = message;
  stream_.expires_after(core_->options.write_timeout);
  http::async_write(
      stream_, *message,
      [self = shared_from_this(), close, status, body_bytes](beast::error_code ec, size_t) {
        self->OnWrite(close, status, body_bytes, ec);
      });
  keep_alive_while_handling_.reset();  // The write's completion holds the session now.
}

void HttpSession::OnWrite(bool close, int status, uint64_t body_bytes, beast::error_code ec) {
  response_.reset();
  ++core_->requests;
  if (status >= 100 && status <= 599) ++core_->responses_by_status[status - 100];
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started_)
          .count();
  char timing[32];
  std::snprintf(timing, sizeof timing, "%.1f ms", ms);
  // The path is logged decoded, without the query and with secret segments redacted: tokens and
  // view-link ids never reach the log.
  core_->Log(status >= 500 ? LogLevel::kWarning : LogLevel::kInfo,
             "HTTP " + remote_ + " " + (method_.empty() ? "-" : Printable(method_, 16)) + " " +
                 LoggedPath() + " " + std::to_string(status) + " " + std::to_string(body_bytes) +
                 " B " + timing + (ec ? " (write failed)" : ""));
  if (state_ == State::kClosed) return;
  if (ec) {
    CloseNow();
  } else if (close) {
    CloseGracefully();
  } else {
    DoReadHeader();
  }
}

void HttpSession::CloseGracefully() {
  state_ = State::kClosing;
  beast::error_code ec;
  stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
  if (ec) {
    CloseNow();
    return;
  }
  drained_ = 0;
  stream_.expires_after(kLingerTime);
  stream_.async_read_some(asio::buffer(drain_),
                          [self = shared_from_this()](beast::error_code read_ec, size_t bytes) {
                            self->OnLinger(read_ec, bytes);
                          });
}

void HttpSession::OnLinger(beast::error_code ec, size_t bytes) {
  if (state_ != State::kClosing) return;
  drained_ += bytes;
  if (ec || drained_ > kMaxLingerBytes) {
    CloseNow();
    return;
  }
  stream_.async_read_some(asio::buffer(drain_),
                          [self = shared_from_this()](beast::error_code read_ec, size_t n) {
                            self->OnLinger(read_ec, n);
                          });
}

void HttpSession::CloseNow() {
  if (state_ == State::kClosed) return;
  state_ = State::kClosed;
  beast::error_code ignored;
  stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
  stream_.close();
  FailPiece(UnavailableError("the connection is closed"));
  // Released last: it may hold the only reference to this session.
  auto last_reference = std::move(keep_alive_while_handling_);
}

}  // namespace octoscope::net::detail
