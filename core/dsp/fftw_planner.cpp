#include "core/dsp/fftw_planner.hpp"

namespace ridgewatch::dsp {

std::mutex& fftw_planner_mutex() {
  static std::mutex mutex;
  return mutex;
}

}  // namespace ridgewatch::dsp
