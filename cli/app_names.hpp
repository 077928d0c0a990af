// The commands are built on the application layer shared with the daemon (app/: configuration and rig
// files, argument and exit-code vocabulary, event JSON, help texts); its names are used unqualified
// inside namespace ridgewatch::cli.
#pragma once

namespace ridgewatch::app {}

namespace ridgewatch::cli {
using namespace ridgewatch::app;
}  // namespace ridgewatch::cli
