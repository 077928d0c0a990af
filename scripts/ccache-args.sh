# Sourced by the build scripts. When ccache is installed, ccache_setup ROOT exports CCACHE_BASEDIR=ROOT
# (so two clones in different folders share cache entries) and fills the array CCACHE_CMAKE_ARGS with
# the cmake arguments that put ccache in front of the compilers; without ccache the array stays empty.
# A second run of the test command on the same machine then recompiles only the files that changed;
# the results are the same either way.
CCACHE_CMAKE_ARGS=()
ccache_setup() {
  if command -v ccache >/dev/null 2>&1; then
    export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$1}"
    # Entries do not depend on the build folder's absolute path (only the debug info's compilation
    # directory would differ, which the tests do not read).
    export CCACHE_NOHASHDIR="${CCACHE_NOHASHDIR:-1}"
    CCACHE_CMAKE_ARGS=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  fi
}
