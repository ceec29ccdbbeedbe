#include "dataset/dataset_description.h"

namespace octoscope::dataset {

protocol::DatasetDescription Describe(const Dataset& dataset) {
  const DatasetStatus status = dataset.status();
  protocol::DatasetDescription d;
  d.id = dataset.id();
  d.name = dataset.name();
  d.info = dataset.info();
  // The scan's warnings, then the dataset's own (a stream's unclean stop).
  d.info.warnings.insert(d.info.warnings.end(), status.warnings.begin(), status.warnings.end());
  d.spacing_um = dataset.spacing_um();
  d.state = std::string(StateName(status.state));
  d.planes_total = status.planes_total;
  d.planes_received = status.planes_received;
  d.planes_inserted = status.planes_inserted;
  d.missing_planes = status.missing_planes;
  d.cache = status.cache_dir.string();
  d.error = status.error;
  d.value_maps = dataset.value_maps();
  return d;
}

std::vector<protocol::HistogramChannelDescription> DescribeHistogram(const Dataset& dataset) {
  const Histogram histogram = dataset.histogram();
  std::vector<protocol::HistogramChannelDescription> channels;
  for (int c = 0; c < histogram.channels(); ++c) channels.push_back(histogram.Describe(c));
  return channels;
}

}  // namespace octoscope::dataset
