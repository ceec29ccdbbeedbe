#include "app/api_routes.h"

#include <algorithm>
#include <optional>
#include <span>
#include <string_view>
#include <utility>
#include <vector>

#include "dataset/dataset_description.h"
#include "protocol/api_json.h"
#include "protocol/dataset_json.h"
#include "protocol/query_string.h"
#include "protocol/ws_messages.h"
#include "volume/data_type.h"

namespace octoscope::app {
namespace {

using net::HttpResponse;

// The HTTP status of an error (docs/api.md).
int HttpStatusFor(const Status& status) {
  switch (status.code()) {
    case StatusCode::kInvalidArgument:
    case StatusCode::kOutOfRange:
    case StatusCode::kCorrupt:
    case StatusCode::kUnsupported:
      return 400;
    case StatusCode::kNotFound:
      return 404;
    case StatusCode::kPermissionDenied:
      return 403;
    case StatusCode::kFailedPrecondition:
      return 409;
    case StatusCode::kResourceExhausted:
      return 413;
    case StatusCode::kUnavailable:
    case StatusCode::kCancelled:
      return 503;
    default:
      return 500;
  }
}

HttpResponse ErrorResponse(const Status& status) {
  return HttpResponse::Error(HttpStatusFor(status), status.message());
}

// 429: an upload that does not fit now; the client retries after a second.
HttpResponse TooManyUploads(std::string_view what) {
  HttpResponse response = HttpResponse::Error(429, std::string(what) + "; retry");
  response.headers.push_back({"Retry-After", "1"});
  return response;
}

// "/api/datasets/ID/rest" → {"ID", "/rest"}; nothing when the path is not below /api/datasets/.
bool SplitDatasetPath(std::string_view path, std::string* id, std::string* rest) {
  constexpr std::string_view kPrefix = "/api/datasets/";
  if (!path.starts_with(kPrefix)) return false;
  path.remove_prefix(kPrefix.size());
  const size_t slash = path.find('/');
  *id = std::string(path.substr(0, slash));
  *rest = slash == std::string_view::npos ? "" : std::string(path.substr(slash));
  return !id->empty();
}

bool IsSlabUpload(const net::HttpRequest& head) {
  std::string id, rest;
  return head.method == "PUT" && SplitDatasetPath(head.path, &id, &rest) && rest == "/slabs";
}

}  // namespace

// The body of one slab upload, pulled from the connection piece by piece (I/O threads: it only
// appends), then inserted on an upload worker. Each pending Read holds the reader alive.
struct ApiRoutes::SlabUpload {
  std::shared_ptr<dataset::Dataset> dataset;
  protocol::SlabQuery query;
  bool tiff = false;
  uint64_t limit = 0;  // Raw: exactly this many bytes; TIFF: at most.
  std::vector<std::byte> body;
  UploadBudget::Reservation admitted;  // Held until the insert has finished.
};

struct ApiRoutes::SlabReader : std::enable_shared_from_this<SlabReader> {
  SlabReader(ApiRoutes* routes, std::shared_ptr<SlabUpload> upload,
             std::shared_ptr<net::BodyReader> reader, net::HttpResponder responder)
      : routes(routes),
        upload(std::move(upload)),
        reader(std::move(reader)),
        responder(std::move(responder)) {}

  void Next() {
    reader->Read([self = shared_from_this()](Result<std::span<const uint8_t>> piece) {
      self->OnPiece(std::move(piece));
    });
  }

  void OnPiece(Result<std::span<const uint8_t>> piece) {
    if (!piece.ok()) return;  // The net layer answered (413/400) or the client left.
    if (!piece->empty()) {
      if (upload->body.size() + piece->size() > upload->limit) {
        return routes->Respond(
            responder,
            HttpResponse::Error(413, "slab body over " + std::to_string(upload->limit) + " bytes"));
      }
      const auto* bytes = reinterpret_cast<const std::byte*>(piece->data());
      upload->body.insert(upload->body.end(), bytes, bytes + piece->size());
      return Next();
    }
    if (!upload->tiff && upload->body.size() != upload->limit) {
      return routes->Respond(
          responder,
          HttpResponse::Error(400, "slab body ended after " + std::to_string(upload->body.size()) +
                                       " of " + std::to_string(upload->limit) + " bytes"));
    }
    routes->SubmitUpload([routes = routes, upload = upload, responder = responder] {
      const protocol::SlabQuery& q = upload->query;
      Status status =
          upload->tiff ? upload->dataset->AddTiffSlab(q.channel, q.z, q.depth, upload->body, q.wait)
                       : upload->dataset->AddSlab(q.channel, q.z, q.depth, upload->body, q.wait);
      upload->body = {};
      upload->admitted.reset();  // Before the answer: the client's next slab finds room.
      if (!status.ok()) return routes->Respond(responder, ErrorResponse(status));
      const dataset::DatasetStatus s = upload->dataset->status();
      routes->Respond(responder,
                      HttpResponse::Json(
                          200, protocol::SlabResultJson(static_cast<int64_t>(s.planes_received),
                                                        static_cast<int64_t>(s.planes_inserted))));
    });
  }

  ApiRoutes* routes;
  std::shared_ptr<SlabUpload> upload;
  std::shared_ptr<net::BodyReader> reader;
  net::HttpResponder responder;
};

ApiRoutes::ApiRoutes(dataset::DatasetRegistry* registry, session::DatasetHub* hub,
                     session::ServerMetrics* metrics, LatestWinsExecutor* uploads,
                     ApiRoutesOptions options)
    : registry_(registry),
      hub_(hub),
      metrics_(metrics),
      uploads_(uploads),
      options_(std::move(options)),
      started_(std::chrono::steady_clock::now()),
      uploads_running_(std::make_shared<std::atomic<int>>(0)),
      upload_budget_(static_cast<uint64_t>(std::max(1, options_.max_concurrent_uploads)) *
                     std::max<uint64_t>(1, options_.max_upload_bytes)) {}

net::BodyMode ApiRoutes::BodyModeFor(const net::HttpRequest& head) {
  return IsSlabUpload(head) ? net::BodyMode::kStreamed : net::BodyMode::kBuffered;
}

void ApiRoutes::Respond(const net::HttpResponder& responder, HttpResponse response) {
  responder.Respond(std::move(response));
}

void ApiRoutes::Handle(net::HttpRequest request, net::HttpResponder responder) {
  const std::string& path = request.path;
  const std::string& method = request.method;
  auto method_not_allowed = [&](std::string_view allow) {
    HttpResponse response = HttpResponse::Error(405, "method " + method + " not allowed");
    response.headers.push_back({"Allow", std::string(allow)});
    Respond(responder, std::move(response));
  };
  if (path == "/api/health") {
    if (method != "GET") return method_not_allowed("GET");
    return Health(responder);
  }
  const net::Principal& principal = request.principal;
  auto forbidden = [&](std::string_view what) {
    Respond(responder, HttpResponse::Error(403, what));
  };
  // Share and view links read, nothing else: no uploads, no streams, no metrics (the dataset
  // scoping of what they read is the access control's).
  if (request.principal.kind != net::Principal::Kind::kUser) {
    const bool readable =
        method == "GET" && (path == "/api/datasets" || path.starts_with("/api/datasets/") ||
                            path.starts_with("/api/views/"));
    if (!readable) {
      return Respond(responder,
                     HttpResponse::Error(403, "share and view links may only read datasets"));
    }
  }
  if (path == "/metrics") {
    if (method != "GET") return method_not_allowed("GET");
    if (options_.access != nullptr && !AccessControl::MayReadMetrics(principal)) {
      return forbidden("the metrics are for admins");
    }
    return Metrics(responder);
  }
  if (path == "/api/datasets") {
    if (method == "GET") {
      std::vector<protocol::DatasetDescription> list;
      for (const auto& dataset : registry_->List()) {
        if (options_.access == nullptr || options_.access->MayView(principal, *dataset)) {
          list.push_back(dataset::Describe(*dataset));
        }
      }
      return Respond(responder, HttpResponse::Json(200, protocol::DatasetListJson(list)));
    }
    if (method == "POST") {
      if (options_.access != nullptr && !AccessControl::MayCreateStreams(principal)) {
        return forbidden("only users create streams");
      }
      return CreateStream(request, responder);
    }
    return method_not_allowed("GET, POST");
  }
  if (path == "/api/views") {
    if (method != "GET") return method_not_allowed("GET");
    return ListViews(request, responder);
  }
  if (path.starts_with("/api/views/")) {
    const std::string view(path.substr(std::string_view("/api/views/").size()));
    if (method == "GET") return GetView(request, view, responder);
    if (method == "DELETE") return DeleteView(request, view, responder);
    return method_not_allowed("GET, DELETE");
  }
  std::string id, rest;
  if (!SplitDatasetPath(path, &id, &rest)) {
    return Respond(responder, HttpResponse::Error(404, "no such path"));
  }
  if (rest == "/slabs") {
    if (method != "PUT") return method_not_allowed("PUT");
    return PutSlab(request, id, responder);
  }
  if (rest == "/finish") {
    if (method != "POST") return method_not_allowed("POST");
    return Finish(request, id, responder);
  }
  std::shared_ptr<dataset::Dataset> dataset = FindVisible(principal, id);
  if (dataset == nullptr || (!rest.empty() && rest != "/histogram")) {
    return Respond(
        responder,
        HttpResponse::Error(404, dataset == nullptr ? "no dataset '" + id + "'" : "no such path"));
  }
  if (method != "GET") return method_not_allowed("GET");
  if (rest.empty()) {
    return Respond(responder,
                   HttpResponse::Json(200, protocol::DatasetJson(dataset::Describe(*dataset))));
  }
  Respond(responder,
          HttpResponse::Json(200, protocol::HistogramJson(dataset::DescribeHistogram(*dataset))));
}

std::shared_ptr<dataset::Dataset> ApiRoutes::FindVisible(const net::Principal& principal,
                                                         const std::string& id) const {
  std::shared_ptr<dataset::Dataset> dataset = registry_->Find(id);
  if (dataset == nullptr || options_.access == nullptr) return dataset;
  return options_.access->MayView(principal, *dataset) ? dataset : nullptr;
}

LatestWinsExecutor* ApiRoutes::state_io() const {
  return options_.state_io != nullptr ? options_.state_io : uploads_;
}

bool ApiRoutes::OwnsView(const net::Principal& principal, const protocol::GrantRef& owner) const {
  if (principal.kind != net::Principal::Kind::kUser) return false;
  if (options_.access == nullptr || principal.admin) return true;
  const std::optional<protocol::GrantRef> mine = options_.access->GrantOf(principal);
  return mine && *mine == owner;
}

void ApiRoutes::GetView(const net::HttpRequest& request, const std::string& id,
                        const net::HttpResponder& responder) {
  session::ViewStore* views = options_.views;
  const std::optional<session::ViewStore::Entry> entry =
      views != nullptr && protocol::IsViewLinkId(id) ? views->Find(id) : std::nullopt;
  // A view link reads its own document; a user the views of datasets they may see, and their
  // own (404 like an unknown id otherwise); a share link none.
  const net::Principal& principal = request.principal;
  bool visible = entry.has_value();
  if (visible && options_.access != nullptr) {
    if (principal.kind == net::Principal::Kind::kView) {
      visible = principal.credential == id;
    } else if (principal.kind == net::Principal::Kind::kShare) {
      visible = false;
    } else if (!principal.admin) {
      const std::shared_ptr<dataset::Dataset> found =
          entry->dataset.empty() ? nullptr : registry_->Find(entry->dataset);
      visible = (found != nullptr && options_.access->MayView(principal, *found)) ||
                (entry->grant && OwnsView(principal, entry->grant->owner));
    }
  }
  if (!visible) return Respond(responder, HttpResponse::Error(404, "no view link '" + id + "'"));
  // The stored document is read (and checked) off the I/O thread.
  state_io()->Post([views, id, responder] {
    auto text = views->LoadText(id);
    if (text.ok()) {
      auto link = protocol::ParseViewLink(*text);
      if (!link.ok()) {
        text = CorruptError("view link " + id +
                            " is not a valid view document: " + link.status().message());
      }
    }
    if (!text.ok()) {
      const int status = text.status().code() == StatusCode::kNotFound ? 404 : 500;
      responder.Respond(HttpResponse::Error(status, text.status().message()));
      return;
    }
    responder.Respond(HttpResponse::Json(200, std::move(*text)));
  });
}

void ApiRoutes::ListViews(const net::HttpRequest& request, const net::HttpResponder& responder) {
  const net::Principal& principal = request.principal;
  if (principal.kind != net::Principal::Kind::kUser) {
    return Respond(responder, HttpResponse::Error(403, "only users list view links"));
  }
  std::vector<protocol::ViewLinkInfo> list;
  if (options_.views != nullptr) {
    const std::string base = options_.link_base != nullptr ? options_.link_base->Get() : "/";
    for (const auto& [id, entry] : options_.views->List()) {
      // Version 1 documents have no owner: only admins see them (to delete them).
      if (entry.grant ? !OwnsView(principal, entry.grant->owner) : !principal.admin) continue;
      protocol::ViewLinkInfo info;
      info.id = id;
      info.url = base + "?view=" + id;
      info.dataset = entry.dataset;
      if (auto found = registry_->Find(entry.dataset)) info.dataset_name = found->name();
      if (entry.grant) {
        const auto kind = entry.grant->creator.kind;
        info.made_through = kind == protocol::GrantRef::Kind::kUser    ? "user"
                            : kind == protocol::GrantRef::Kind::kShare ? "share"
                                                                       : "view";
        info.created_unix_s = entry.grant->created_unix_s;
        info.expires_unix_s = entry.grant->expires_unix_s;
        if (options_.access != nullptr) {
          info.owner = options_.access->UserName(entry.grant->owner.id).value_or("");
        }
      } else {
        info.made_through = "unknown";
      }
      if (options_.access != nullptr) {
        const session::GrantVerdict verdict =
            options_.access->Check({protocol::GrantRef::Kind::kView, id}, "");
        info.valid = verdict.holds;
        info.reason = verdict.reason;
      } else {
        info.valid = true;
      }
      list.push_back(std::move(info));
    }
  }
  std::sort(list.begin(), list.end(), [](const auto& a, const auto& b) {
    return a.created_unix_s != b.created_unix_s ? a.created_unix_s > b.created_unix_s : a.id < b.id;
  });
  Respond(responder, HttpResponse::Json(200, protocol::ViewLinkListJson(list)));
}

void ApiRoutes::DeleteView(const net::HttpRequest& request, const std::string& id,
                           const net::HttpResponder& responder) {
  session::ViewStore* views = options_.views;
  const std::optional<session::ViewStore::Entry> entry =
      views != nullptr && protocol::IsViewLinkId(id) ? views->Find(id) : std::nullopt;
  const bool owner = entry && (entry->grant ? OwnsView(request.principal, entry->grant->owner)
                                            : request.principal.admin);
  if (!owner) return Respond(responder, HttpResponse::Error(404, "no view link '" + id + "'"));
  // Unlinking (and the directory's fsync) runs off the I/O thread. The link stops opening at
  // once; sessions opened through it end at their next revalidation.
  state_io()->Post([views, id, responder] {
    Status deleted = views->Delete(id);
    if (!deleted.ok()) {
      const int status = deleted.code() == StatusCode::kNotFound ? 404 : 500;
      responder.Respond(HttpResponse::Error(status, deleted.message()));
      return;
    }
    HttpResponse response;
    response.status = 204;
    responder.Respond(std::move(response));
  });
}

bool ApiRoutes::MayFeed(const net::Principal& principal, const dataset::Dataset& dataset,
                        const net::HttpResponder& responder) {
  if (options_.access == nullptr) return true;
  if (!AccessControl::MayCreateStreams(principal)) {
    Respond(responder, HttpResponse::Error(403, "only users send planes or finish streams"));
    return false;
  }
  // The demo is everyone's to look at, and only the admins' to change.
  if (dataset.id() == dataset::DemoDatasetId() && !principal.admin) {
    Respond(responder, HttpResponse::Error(403, "only admins send planes to or finish the demo"));
    return false;
  }
  return true;
}

void ApiRoutes::Health(const net::HttpResponder& responder) {
  protocol::HealthInfo health;
  health.version = options_.version;
  health.uptime_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  health.datasets = static_cast<int64_t>(registry_->List().size());
  health.sessions = metrics_ != nullptr ? metrics_->sessions() : 0;
  Respond(responder, HttpResponse::Json(200, protocol::HealthJson(health)));
}

void ApiRoutes::Metrics(const net::HttpResponder& responder) {
  std::string text = metrics_ != nullptr ? metrics_->PrometheusText() : std::string();
  const auto datasets = registry_->List();
  session::AppendMetricHeader(&text, "octoscope_dataset_planes_inserted", "gauge",
                              "Planes (z x channels) visible in the octree.");
  for (const auto& dataset : datasets) {
    text += "octoscope_dataset_planes_inserted{dataset=\"" +
            session::EscapeLabelValue(dataset->id()) + "\"} " +
            std::to_string(dataset->status().planes_inserted) + "\n";
  }
  session::AppendMetricHeader(&text, "octoscope_dataset_planes_total", "gauge",
                              "Planes (z x channels) of the dataset.");
  for (const auto& dataset : datasets) {
    text += "octoscope_dataset_planes_total{dataset=\"" + session::EscapeLabelValue(dataset->id()) +
            "\"} " + std::to_string(dataset->status().planes_total) + "\n";
  }
  session::AppendMetricHeader(&text, "octoscope_dataset_open", "gauge",
                              "1 while the dataset's octree and page cache are in memory.");
  for (const auto& dataset : datasets) {
    text += "octoscope_dataset_open{dataset=\"" + session::EscapeLabelValue(dataset->id()) +
            "\"} " + (dataset->status().open ? "1" : "0") + "\n";
  }
  session::AppendMetricHeader(&text, "octoscope_dataset_ram_budget_bytes", "gauge",
                              "The dataset's share of the RAM budget (open datasets).");
  for (const auto& dataset : datasets) {
    if (!dataset->status().open) continue;
    text += "octoscope_dataset_ram_budget_bytes{dataset=\"" +
            session::EscapeLabelValue(dataset->id()) + "\"} " +
            std::to_string(dataset->ram_budget()) + "\n";
  }
  session::AppendMetricHeader(&text, "octoscope_ram_budget_bytes", "gauge",
                              "The RAM budget divided among the open datasets (--ram-mb).");
  text += "octoscope_ram_budget_bytes " + std::to_string(registry_->ram_bytes()) + "\n";
  if (hub_ != nullptr) {
    session::AppendMetricHeader(&text, "octoscope_dataset_releases_total", "counter",
                                "Datasets closed after idle-timeout-s without a session.");
    text += "octoscope_dataset_releases_total " + std::to_string(hub_->releases()) + "\n";
  }
  HttpResponse response;
  response.status = 200;
  response.content_type = "text/plain; version=0.0.4; charset=utf-8";
  response.body = std::move(text);
  Respond(responder, std::move(response));
}

void ApiRoutes::CreateStream(const net::HttpRequest& request, const net::HttpResponder& responder) {
  auto parsed =
      protocol::ParseStreamRequest(request.body, protocol::StreamRequestKind::kApi, "request body");
  if (!parsed.ok()) return Respond(responder, ErrorResponse(parsed.status()));
  std::optional<protocol::GrantRef> creator;
  if (options_.access != nullptr) creator = options_.access->GrantOf(request.principal);
  if (creator) {
    // Each unfinished stream holds threads and a share of everyone's RAM: a few per user.
    int unfinished = 0;
    for (const auto& dataset : registry_->List()) {
      unfinished += dataset->is_stream() &&
                    dataset->status().state == dataset::DatasetState::kStreaming &&
                    AccessControl::CreatorOf(*dataset) == creator;
    }
    if (unfinished >= options_.max_streams_per_user) {
      HttpResponse response = HttpResponse::Error(
          429, "too many unfinished streams (at most " +
                   std::to_string(options_.max_streams_per_user) + " per user): finish one first");
      response.headers.push_back({"Retry-After", "60"});
      return Respond(responder, std::move(response));
    }
  }
  // Creating the cache directory touches the disk: an upload worker does it.
  RunUpload(responder, [this, responder, spec = std::move(*parsed), creator] {
    // The creator's grant, kept with the stream (its record) across restarts.
    auto created =
        registry_->CreateStream(spec, creator ? protocol::GrantRefText(*creator) : std::string());
    if (!created.ok()) return Respond(responder, ErrorResponse(created.status()));
    Respond(responder, HttpResponse::Json(201, protocol::CreatedJson((*created)->id())));
  });
}

void ApiRoutes::PutSlab(const net::HttpRequest& request, const std::string& id,
                        const net::HttpResponder& responder) {
  auto query = protocol::ParseSlabQuery(request.query);
  if (!query.ok()) return Respond(responder, ErrorResponse(query.status()));
  auto upload = std::make_shared<SlabUpload>();
  upload->dataset = FindVisible(request.principal, id);
  if (upload->dataset == nullptr) {
    return Respond(responder, HttpResponse::Error(404, "no dataset '" + id + "'"));
  }
  if (!MayFeed(request.principal, *upload->dataset, responder)) return;
  if (!upload->dataset->is_stream()) {
    return Respond(responder, HttpResponse::Error(409, "dataset '" + id + "' is not a stream"));
  }
  upload->query = *query;
  const std::string_view type = request.Header("Content-Type");
  upload->tiff = type.starts_with("image/tiff");
  if (!upload->tiff && !type.empty() && !type.starts_with("application/octet-stream")) {
    return Respond(responder, HttpResponse::Error(415,
                                                  "Content-Type must be application/octet-stream "
                                                  "(raw little-endian samples) or image/tiff"));
  }
  const volume::VolumeInfo& info = upload->dataset->info();
  const uint64_t raw_bytes =
      info.PlaneVoxels() * static_cast<uint64_t>(query->depth) * volume::BytesPerSample(info.dtype);
  // A slab's planes are at most --max-upload-mb, sent raw or decoded from a (smaller) TIFF.
  if (raw_bytes > options_.max_upload_bytes) {
    return Respond(responder,
                   HttpResponse::Error(
                       413, std::to_string(query->depth) + " planes of this dataset are " +
                                std::to_string(raw_bytes) + " bytes, over the upload limit of " +
                                std::to_string(options_.max_upload_bytes) + " bytes"));
  }
  upload->limit =
      upload->tiff ? std::min(dataset::kMaxTiffSlabBytes, options_.max_upload_bytes) : raw_bytes;
  const auto length = request.body_reader->content_length();
  if (!upload->tiff && length && *length != raw_bytes) {
    return Respond(
        responder,
        HttpResponse::Error(400, "slab body is " + std::to_string(*length) + " bytes; " +
                                     std::to_string(query->depth) + " planes of this dataset are " +
                                     std::to_string(raw_bytes)));
  }
  if (length && *length > upload->limit) {
    return Respond(responder, HttpResponse::Error(413, "slab body too large"));
  }
  // Admitted before a byte of the body is read: its body (a TIFF's declared length, or its limit)
  // and the planes a TIFF decodes to. Answered without reading the body otherwise ("100 Continue"
  // is never sent; a body already on its way closes the connection).
  const uint64_t ram = upload->tiff ? length.value_or(upload->limit) + raw_bytes : raw_bytes;
  std::optional<UploadBudget::Reservation> admitted = upload_budget_.TryReserve(ram);
  if (!admitted) {
    return Respond(responder,
                   TooManyUploads("too many slab uploads at once (their bodies would pass " +
                                  std::to_string(upload_budget_.capacity() >> 20) + " MiB)"));
  }
  upload->admitted = std::move(*admitted);
  if (length) upload->body.reserve(*length);
  std::make_shared<SlabReader>(this, std::move(upload), request.body_reader, responder)->Next();
}

void ApiRoutes::Finish(const net::HttpRequest& request, const std::string& id,
                       const net::HttpResponder& responder) {
  std::shared_ptr<dataset::Dataset> dataset = FindVisible(request.principal, id);
  if (dataset == nullptr) {
    return Respond(responder, HttpResponse::Error(404, "no dataset '" + id + "'"));
  }
  if (!MayFeed(request.principal, *dataset, responder)) return;
  if (!dataset->is_stream()) {
    return Respond(responder, HttpResponse::Error(409, "dataset '" + id + "' is not a stream"));
  }
  RunUpload(responder, [this, dataset, responder] {
    Status status = dataset->Finish();
    if (!status.ok()) return Respond(responder, ErrorResponse(status));
    Respond(responder, HttpResponse::Json(200, protocol::DatasetJson(dataset::Describe(*dataset))));
  });
}

bool ApiRoutes::RunUpload(const net::HttpResponder& responder, std::function<void()> job) {
  if (uploads_running_->fetch_add(1) >= options_.max_concurrent_uploads) {
    uploads_running_->fetch_sub(1);
    Respond(responder, TooManyUploads("too many concurrent uploads"));
    return false;
  }
  SubmitUpload([running = uploads_running_, job = std::move(job)] {
    // Released even when the job throws (the executor catches; the responder's
    // last copy then answers 500).
    struct Release {
      std::atomic<int>* n;
      ~Release() { n->fetch_sub(1); }
    } release{running.get()};
    job();
  });
  return true;
}

void ApiRoutes::SubmitUpload(std::function<void()> job) {
  uploads_->Submit(next_upload_.fetch_add(1), std::move(job));
}

}  // namespace octoscope::app
