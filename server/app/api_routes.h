// ApiRoutes: the REST API of `octoscope serve` (docs/api.md) on top of the dataset registry —
// health, metrics, the dataset list, histograms, streaming ingest (create, slabs, finish) and
// stored view links (GET /api/views: the caller's own; GET and DELETE /api/views/{id}).
// Every dataset-scoped route answers only for datasets the request's principal may see
// (AccessControl; others are 404 like unknown ids); /metrics is for admins, creating and
// feeding streams for users (within max_streams_per_user unfinished ones each; the demo only for
// admins), listing and deleting view links for their owners (and admins).
// The net layer hands requests over on I/O threads; everything that touches disk or the octree
// (slab inserts, finishing a stream) runs on the upload workers, and slab bodies are pulled from
// the connection piece by piece into one buffer of exactly the expected size. A slab upload is
// admitted into the UploadBudget (its body, and a TIFF's decoded planes) before the first byte of
// its body is read, and holds its place until its insert has finished; one that does not fit gets
// 429 with Retry-After, its body unread.
//
// Thread safety: Handle may be called from any I/O thread concurrently.
#ifndef OCTOSCOPE_APP_API_ROUTES_H_
#define OCTOSCOPE_APP_API_ROUTES_H_

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "app/access_control.h"
#include "app/upload_budget.h"
#include "dataset/dataset_registry.h"
#include "net/api_handler.h"
#include "session/dataset_hub.h"
#include "session/server_metrics.h"
#include "session/view_session.h"
#include "session/view_store.h"
#include "util/latest_wins_executor.h"

namespace octoscope::app {

struct ApiRoutesOptions {
  std::string version;
  // Who sees what (REQUIRED in `serve`; null admits every principal to everything, for tests of
  // other routes).
  const AccessControl* access = nullptr;
  // Creating and finishing streams: at most this many at once (429 beyond). Slab uploads: their
  // bodies and decoded planes hold at most max_concurrent_uploads x max_upload_bytes of RAM.
  int max_concurrent_uploads = 8;
  uint64_t max_upload_bytes = uint64_t{1} << 30;  // --max-upload-mb: a slab's planes at most.
  session::ViewStore* views = nullptr;  // /api/views; null: 404.
  // Disk I/O of view links (reading, deleting); null: the upload workers.
  LatestWinsExecutor* state_io = nullptr;
  const session::LinkBase* link_base = nullptr;  // URLs in GET /api/views; null: relative.
  int max_streams_per_user = 8;  // Unfinished streams one user created; more: 429.
};

class ApiRoutes : public net::ApiHandler {
 public:
  // All pointers must outlive the routes (and the server that calls them).
  ApiRoutes(dataset::DatasetRegistry* registry, session::DatasetHub* hub,
            session::ServerMetrics* metrics, LatestWinsExecutor* uploads, ApiRoutesOptions options);

  net::BodyMode BodyModeFor(const net::HttpRequest& head) override;
  void Handle(net::HttpRequest request, net::HttpResponder responder) override;

 private:
  struct SlabUpload;
  struct SlabReader;

  void Health(const net::HttpResponder& responder);
  void Metrics(const net::HttpResponder& responder);
  // The dataset `id` when `principal` may see it, else null (as for an unknown id).
  std::shared_ptr<dataset::Dataset> FindVisible(const net::Principal& principal,
                                                const std::string& id) const;
  void CreateStream(const net::HttpRequest& request, const net::HttpResponder& responder);
  void PutSlab(const net::HttpRequest& request, const std::string& id,
               const net::HttpResponder& responder);
  void Finish(const net::HttpRequest& request, const std::string& id,
              const net::HttpResponder& responder);
  void GetView(const net::HttpRequest& request, const std::string& id,
               const net::HttpResponder& responder);
  void ListViews(const net::HttpRequest& request, const net::HttpResponder& responder);
  void DeleteView(const net::HttpRequest& request, const std::string& id,
                  const net::HttpResponder& responder);
  // Whether `principal` may delete (and sees in its list) a view link owned by `owner`.
  bool OwnsView(const net::Principal& principal, const protocol::GrantRef& owner) const;
  // Answers 403 and returns false when `dataset` may not be fed or finished by `principal`.
  bool MayFeed(const net::Principal& principal, const dataset::Dataset& dataset,
               const net::HttpResponder& responder);
  LatestWinsExecutor* state_io() const;
  // Runs `job` on an upload worker; false (and 429 sent) when too many run already.
  bool RunUpload(const net::HttpResponder& responder, std::function<void()> job);
  // Runs `job` on an upload worker, admitted already.
  void SubmitUpload(std::function<void()> job);
  void Respond(const net::HttpResponder& responder, net::HttpResponse response);

  dataset::DatasetRegistry* registry_;
  session::DatasetHub* hub_;
  session::ServerMetrics* metrics_;
  LatestWinsExecutor* uploads_;
  const ApiRoutesOptions options_;
  const std::chrono::steady_clock::time_point started_;
  std::atomic<uint64_t> next_upload_{1};
  std::shared_ptr<std::atomic<int>> uploads_running_;
  UploadBudget upload_budget_;  // Slab uploads.
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_API_ROUTES_H_
