// The status page: one static HTML document with its script, embedded in the
// binary. It polls GET /api/status and reloads the images when a new
// detection arrives.
#pragma once

#include <string_view>

namespace bp::internal {

std::string_view StatusPageHtml();

}  // namespace bp::internal
