// The test binary's entry point: doctest's runner, plus the skip protocol of common.hpp: when
// no case failed but some case (or part of one) was skipped for a missing prerequisite, the exit
// code is kSkipExitCode so that CTest (SKIP_RETURN_CODE) reports the entry as skipped, not passed.
#define DOCTEST_CONFIG_IMPLEMENT
#include <cstdio>

#include "common.hpp"

int main(int argc, char** argv) {
  doctest::Context context(argc, argv);
  const int result = context.run();
  if (context.shouldExit()) return result;
  if (result == 0 && qdo::test::skipped_parts() > 0) {
    std::printf("%d test part(s) skipped for a missing prerequisite (see SKIPPED: lines); exit %d\n",
                qdo::test::skipped_parts(), qdo::test::kSkipExitCode);
    return qdo::test::kSkipExitCode;
  }
  return result;
}
