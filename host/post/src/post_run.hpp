// What storetrack-post does once its command line parsed: read the recording, rebuild the host's
// options and inputs from it (or the substitutes), replay, compare and write the outputs.
#pragma once

#include "post_options.hpp"

namespace storetrack::post {

/// Returns the exit code: 0, 1 (samples differ under --verify, or an output failed to write),
/// 2 (bad input: a message on stderr names the file).
int run_post(const PostOptions& o);

}  // namespace storetrack::post
