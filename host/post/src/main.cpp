// storetrack-post: reprocesses a storetrack-host recording (docs/post-processing.md).
// Exit codes: 0 ok, 1 the replayed samples differ from the recorded ones (--verify) or an output
// could not be written, 2 bad arguments or input.
#include "post_options.hpp"
#include "post_run.hpp"

int main(int argc, char** argv) {
  storetrack::post::PostOptions options;
  if (const int rc = storetrack::post::parse_post_options(argc, argv, options); rc >= 0) return rc;
  return storetrack::post::run_post(options);
}
