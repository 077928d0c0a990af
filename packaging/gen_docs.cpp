// Build-time generator: writes the man pages and the bash completion from the usage table
// (app/usage.cpp) and the documented configuration (config/ridgewatch.yaml), so they cannot drift
// from `--help` and the configuration.
//   gen_docs CONFIG_YAML OUT_DIR  ->  OUT_DIR/ridgewatch.1 ridgewatchd.8 ridgewatch.yaml.5 ridgewatch.bash-completion
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "app/usage.hpp"
#include "ridgewatch_version.hpp"

namespace {

bool write(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  f.close();
  if (!f) std::cerr << "gen_docs: cannot write " << path << "\n";
  return static_cast<bool>(f);
}

}  // namespace

int main(int argc, char** argv) {
  namespace usage = ridgewatch::app::usage;
  if (argc != 3) {
    std::cerr << "usage: gen_docs CONFIG_YAML OUT_DIR\n";
    return 2;
  }
  std::ifstream in(argv[1]);
  if (!in) {
    std::cerr << "gen_docs: cannot read " << argv[1] << "\n";
    return 2;
  }
  std::ostringstream config;
  config << in.rdbuf();
  const std::string dir = argv[2];
  const bool ok = write(dir + "/ridgewatch.1", usage::man_ridgewatch(RIDGEWATCH_VERSION)) &&
                  write(dir + "/ridgewatchd.8", usage::man_ridgewatchd(RIDGEWATCH_VERSION)) &&
                  write(dir + "/ridgewatch.yaml.5", usage::man_config(RIDGEWATCH_VERSION, config.str())) &&
                  write(dir + "/ridgewatch.bash-completion", usage::bash_completion());
  return ok ? 0 : 1;
}
