#include <ostream>

#include "cli/args.hpp"
#include "cli/commands.hpp"

namespace ridgewatch::cli {

int run_modes(const std::vector<std::string>&, std::ostream&, std::ostream& err) {
  err << "modes: under construction\n";
  return 1;
}

}  // namespace ridgewatch::cli
