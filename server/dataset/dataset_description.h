// Describe: a dataset as the API and the WebSocket events show it (protocol::DatasetDescription,
// docs/api.md): identity, metadata, state and progress, taken from one status() snapshot.
//
// Thread safety: thread-safe (Dataset's accessors are).
#ifndef OCTOSCOPE_DATASET_DATASET_DESCRIPTION_H_
#define OCTOSCOPE_DATASET_DATASET_DESCRIPTION_H_

#include <vector>

#include "dataset/dataset.h"
#include "protocol/dataset_json.h"

namespace octoscope::dataset {

protocol::DatasetDescription Describe(const Dataset& dataset);
// The API's histogram channels of the dataset (all voxels counted so far).
std::vector<protocol::HistogramChannelDescription> DescribeHistogram(const Dataset& dataset);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DATASET_DESCRIPTION_H_
