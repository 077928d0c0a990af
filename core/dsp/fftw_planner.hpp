// FFTW's planner (plan creation and destruction) is not thread-safe; every FFTW plan in ridgewatch is
// made and destroyed while holding this one lock. Executing a plan needs no lock.
#pragma once

#include <mutex>

namespace ridgewatch::dsp {

std::mutex& fftw_planner_mutex();

}  // namespace ridgewatch::dsp
