// ApiHandler and WsHandler implementations for the net tests: they behave like the app's will
// (answers from other threads, streamed uploads consumed on a worker, WebSocket messages sent
// from foreign threads) and record what they saw so tests can check it.
#ifndef OCTOSCOPE_TESTS_NET_TEST_HANDLERS_H_
#define OCTOSCOPE_TESTS_NET_TEST_HANDLERS_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "net/api_handler.h"
#include "net/ws_handler.h"
#include "util/strings.h"

namespace octoscope::net::testing {

// One worker thread running posted tasks in order (the app's slow-work threads).
class TaskQueue {
 public:
  TaskQueue() : thread_([this] { Run(); }) {}
  ~TaskQueue() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  void Post(std::function<void()> task) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      tasks_.push_back(std::move(task));
    }
    cv_.notify_all();
  }

 private:
  void Run() {
    for (;;) {
      std::function<void()> task;
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [&] { return stop_ || !tasks_.empty(); });
        if (tasks_.empty()) return;
        task = std::move(tasks_.front());
        tasks_.pop_front();
      }
      task();
    }
  }

  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> tasks_;
  bool stop_ = false;
  std::thread thread_;
};

// FNV-1a over bytes: the checksum both the upload handler and the tests compute.
inline uint64_t Fnv1a(const uint8_t* data, size_t size, uint64_t hash = 1469598103934665603ull) {
  for (size_t i = 0; i < size; ++i) hash = (hash ^ data[i]) * 1099511628211ull;
  return hash;
}

// Routes:
//   /api/health           {"status":"ok"} (no token needed: the net layer lets it through)
//   /api/echo             {"method","path","query","body_bytes","authorization","principal",
//                         "remote","scheme"}
//   /api/slow             answered from the worker once Release() was called
//   /api/drop             the responder is dropped unanswered
//   /api/throw            Handle throws
//   /api/upload (PUT)     streamed: pieces are consumed on the worker; {"bytes":N,"fnv":H}
//   /metrics              text/plain
// "user:NAME[:admin]", "share:CREDENTIAL" or "view:CREDENTIAL".
inline std::string Describe(const Principal& p) {
  switch (p.kind) {
    case Principal::Kind::kUser:
      return "user:" + p.user + (p.admin ? ":admin" : "");
    case Principal::Kind::kShare:
      return "share:" + p.credential;
    case Principal::Kind::kView:
      return "view:" + p.credential;
  }
  return "?";
}

class TestApi : public ApiHandler {
 public:
  BodyMode BodyModeFor(const HttpRequest& head) override {
    return head.path == "/api/upload" ? BodyMode::kStreamed : BodyMode::kBuffered;
  }

  void Handle(HttpRequest request, HttpResponder responder) override {
    {
      std::lock_guard<std::mutex> lock(mu_);
      seen_.push_back(request.method + " " + request.path + "?" + request.query);
      for (const HttpHeader& h : request.headers) seen_headers_.push_back(h.name + ": " + h.value);
    }
    if (request.path == "/api/health") {
      responder.Respond(HttpResponse::Json(200, "{\"status\":\"ok\"}"));
    } else if (request.path == "/api/echo") {
      std::string auth(request.Header("Authorization"));
      responder.Respond(HttpResponse::Json(
          200,
          "{\"method\":\"" + request.method + "\",\"path\":\"" + request.path + "\",\"query\":\"" +
              request.query + "\",\"body_bytes\":" + std::to_string(request.body.size()) +
              ",\"authorization\":\"" + auth + "\",\"principal\":\"" + Describe(request.principal) +
              "\",\"remote\":\"" + request.remote + "\",\"scheme\":\"" + request.scheme + "\"}"));
    } else if (request.path == "/api/slow") {
      ++slow_started_;
      worker_.Post([release = released_, responder] {
        release.wait();
        responder.Respond(HttpResponse::Json(200, "{\"slow\":true}"));
      });
    } else if (request.path == "/api/drop") {
      // The responder goes out of scope unanswered.
    } else if (request.path == "/api/throw") {
      throw std::runtime_error("handler failure");
    } else if (request.path == "/api/upload") {
      StartUpload(std::move(request), std::move(responder));
    } else if (request.path == "/metrics") {
      HttpResponse r;
      r.content_type = "text/plain; version=0.0.4";
      r.body = "octoscope_sessions 0\n";
      responder.Respond(std::move(r));
    } else {
      responder.Respond(HttpResponse::Error(404, "no such API path"));
    }
  }

  void Release() { release_.set_value(); }
  int slow_started() const { return slow_started_; }

  std::vector<std::string> seen() const {
    std::lock_guard<std::mutex> lock(mu_);
    return seen_;
  }
  std::vector<std::string> seen_headers() const {
    std::lock_guard<std::mutex> lock(mu_);
    return seen_headers_;
  }
  // The status the last upload's reader ended with (OK at the end of the body).
  std::optional<Status> upload_end() const {
    std::lock_guard<std::mutex> lock(mu_);
    return upload_end_;
  }
  uint64_t upload_pieces() const { return upload_pieces_; }

 private:
  struct Upload {
    std::shared_ptr<BodyReader> reader;
    HttpResponder responder;
    uint64_t bytes = 0;
    uint64_t hash = 1469598103934665603ull;
  };

  void StartUpload(HttpRequest request, HttpResponder responder) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      upload_end_.reset();
    }
    auto upload = std::make_shared<Upload>(Upload{request.body_reader, std::move(responder)});
    ReadNext(upload);
  }

  // Pulls one piece; the bytes are consumed on the worker, which then asks for the next.
  void ReadNext(std::shared_ptr<Upload> upload) {
    upload->reader->Read([this, upload](Result<std::span<const uint8_t>> piece) {
      if (!piece.ok()) {
        std::lock_guard<std::mutex> lock(mu_);
        upload_end_ = piece.status();
        return;  // The net layer has answered or the client is gone.
      }
      if (piece->empty()) {
        {
          std::lock_guard<std::mutex> lock(mu_);
          upload_end_ = Status::Ok();
        }
        upload->responder.Respond(
            HttpResponse::Json(200, "{\"bytes\":" + std::to_string(upload->bytes) +
                                        ",\"fnv\":" + std::to_string(upload->hash) + "}"));
        return;
      }
      ++upload_pieces_;
      const std::span<const uint8_t> bytes = *piece;
      worker_.Post([this, upload, bytes] {
        upload->bytes += bytes.size();
        upload->hash = Fnv1a(bytes.data(), bytes.size(), upload->hash);
        ReadNext(upload);
      });
    });
  }

  mutable std::mutex mu_;
  std::vector<std::string> seen_;
  std::vector<std::string> seen_headers_;
  std::optional<Status> upload_end_;
  std::atomic<uint64_t> upload_pieces_{0};
  std::atomic<int> slow_started_{0};
  std::promise<void> release_;
  std::shared_future<void> released_ = release_.get_future().share();
  TaskQueue worker_;  // Last: joined first, while the rest is still alive.
};

// What the WebSocket handlers of a test saw, shared by all of its connections.
class WsRecorder {
 public:
  void Opened(const std::string& query, std::shared_ptr<WsSink> sink) {
    std::lock_guard<std::mutex> lock(mu_);
    sinks_[query] = std::move(sink);
    ++opens_;
  }
  void Closed(const std::string& query, const WsCloseInfo& info) {
    std::lock_guard<std::mutex> lock(mu_);
    closes_[query] = info;
    ++close_count_;
  }
  void Text(const std::string& text) {
    std::lock_guard<std::mutex> lock(mu_);
    texts_.push_back(text);
  }
  void Done(bool sent) {
    std::lock_guard<std::mutex> lock(mu_);
    (sent ? sent_ : unsent_)++;
  }

  std::shared_ptr<WsSink> sink(const std::string& query) const {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = sinks_.find(query);
    return it == sinks_.end() ? nullptr : it->second;
  }
  std::optional<WsCloseInfo> closed(const std::string& query) const {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = closes_.find(query);
    if (it == closes_.end()) return std::nullopt;
    return it->second;
  }
  int opens() const {
    std::lock_guard<std::mutex> lock(mu_);
    return opens_;
  }
  int close_count() const {
    std::lock_guard<std::mutex> lock(mu_);
    return close_count_;
  }
  int sent() const {
    std::lock_guard<std::mutex> lock(mu_);
    return sent_;
  }
  int unsent() const {
    std::lock_guard<std::mutex> lock(mu_);
    return unsent_;
  }
  // Drops the sinks (a test that checks memory must not keep connections' sinks alive).
  void Clear() {
    std::lock_guard<std::mutex> lock(mu_);
    sinks_.clear();
    closes_.clear();
    texts_.clear();
  }

 private:
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<WsSink>> sinks_;
  std::map<std::string, WsCloseInfo> closes_;
  std::vector<std::string> texts_;
  int opens_ = 0;
  int close_count_ = 0;
  int sent_ = 0;
  int unsent_ = 0;
};

// Echoes text; "bin:N" answers with N binary bytes (value i % 251), "burst:N" with N texts,
// "close:CODE" closes with CODE, "throw" throws. The connection's query names it in the
// recorder.
class EchoHandler : public WsHandler {
 public:
  EchoHandler(std::shared_ptr<WsRecorder> recorder, std::string query)
      : recorder_(std::move(recorder)), query_(std::move(query)) {}

  void OnOpen(std::shared_ptr<WsSink> sink) override {
    sink_ = sink;
    recorder_->Opened(query_, std::move(sink));
  }

  void OnText(std::string text) override {
    recorder_->Text(text);
    if (text.starts_with("bin:")) {
      const size_t n = static_cast<size_t>(ParseInt64(text.substr(4)).value_or(0));
      auto data = std::make_shared<std::vector<uint8_t>>(n);
      for (size_t i = 0; i < n; ++i) (*data)[i] = static_cast<uint8_t>(i % 251);
      sink_->SendBinary(std::move(data), [r = recorder_](bool sent) { r->Done(sent); });
    } else if (text.starts_with("burst:")) {
      const int64_t n = ParseInt64(text.substr(6)).value_or(0);
      for (int64_t i = 0; i < n; ++i) sink_->SendText("message " + std::to_string(i));
    } else if (text.starts_with("close:")) {
      sink_->Close(static_cast<uint16_t>(ParseInt64(text.substr(6)).value_or(1000)), "bye");
    } else if (text == "throw") {
      throw std::runtime_error("handler failure");
    } else {
      sink_->SendText(std::move(text));
    }
  }

  void OnClose(const WsCloseInfo& info) override { recorder_->Closed(query_, info); }

 private:
  std::shared_ptr<WsRecorder> recorder_;
  std::string query_;
  std::shared_ptr<WsSink> sink_;
};

}  // namespace octoscope::net::testing

#endif  // OCTOSCOPE_TESTS_NET_TEST_HANDLERS_H_
