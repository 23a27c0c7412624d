// The preamble of every LibTorch test (suite "net"): LibTorch first, since its glog-style CHECK
// macros (which abort) must then be replaced by doctest's, then the tests' common helpers.
#pragma once
#include "qdo/net/resunet.hpp"
#undef CHECK
#undef CHECK_EQ
#undef CHECK_NE
#undef CHECK_LE
#undef CHECK_LT
#undef CHECK_GE
#undef CHECK_GT

#include "../common.hpp"
