// Cancellation points of the long computations (Ctrl-C during the final stages, issue 17).
#pragma once

#include <functional>

namespace slscan::core {

// Called by a long computation at its cancellation points: per view, per ICP iteration, per block
// of points, voxels or vertices, per hole, never per pixel. It returns to go on, or throws (the
// reconstruction's ReconstructionInterrupted) to stop; the computation lets the exception pass,
// from worker threads too (tbb::parallel_for rethrows it in the caller). Empty: never stops.
// Called from several threads at once, so it must be thread-safe (it reads an atomic flag).
using InterruptionPoint = std::function<void()>;

inline void interruption_point(const InterruptionPoint& check) {
  if (check) check();
}

}  // namespace slscan::core
