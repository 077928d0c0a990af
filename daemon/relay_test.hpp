// `ridgewatchd --test-relays`: cycles the configured alarm relay lines so the wiring can be checked
// before the monitor is trusted with them.
#pragma once

#include <chrono>
#include <iosfwd>

#include "daemon/daemon.hpp"

namespace ridgewatch::daemon {

/// Asks for confirmation on `in` ("yes") unless `confirmed`, then for each configured relay (alert,
/// danger) in turn: energised (healthy), de-energised (alarm), energised, de-energised, `hold` each,
/// saying each step on `out`; every relay ends de-energised (alarm), as with the daemon stopped.
/// Returns 0 when done, 2 when no relay line is configured or the answer was not "yes"; a relay
/// write that fails is reported and makes the result 3.
int test_relays(GpioLines& lines, std::istream& in, std::ostream& out, bool confirmed, std::chrono::milliseconds hold);

}  // namespace ridgewatch::daemon
