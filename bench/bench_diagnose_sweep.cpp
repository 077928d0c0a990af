// Acceptance sweep of `diagnose` on records of the independent gear-rig generator
// (tests/support/indep_gear.hpp: its own integrator, Hann pulse and noise, no code shared with
// core/model): one hidden catalogue effect per record at the sizes of the README's diagnose sweep,
// several seeds each, and controls with nothing hidden. Prints one line per run and the confusion
// matrix (hidden effect × verdict). Not a Google Benchmark.
//
//   bench_diagnose_sweep [seeds] [controls] [duration_s] [rate_hz] [case,case,...]
//     seeds       per hidden catalogue effect (default 3)
//     controls    records with nothing hidden (default 20)
//     duration_s  record length (default 0.64 s = 16 impacts; damping_drift always >= 2 s, a drift
//                 shows only across the impacts); diagnose fits 16 impacts spread over the record
//     rate_hz     sample rate (default 25600)
//     cases       comma-separated case names of indep::sweep_cases() (default: every catalogue case
//                 and the controls; the out-of-catalogue ones only when named)
// A verdict is "right" when it is exactly the hidden effect with nothing ambiguous; a control is a
// false alarm when anything is accepted, listed as ambiguous or proposed by term discovery.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "core/diagnosis/diagnose.hpp"
#include "../tests/support/indep_gear.hpp"

namespace rd = ridgewatch::diagnosis;
namespace rm = ridgewatch::model;
namespace ig = ridgewatch::testsupport::indep;

namespace {

struct Options {
  int seeds = 3, controls = 20;
  double duration_s = 0.64, rate_hz = 25600.0;
  std::vector<std::string> only;
};

struct Run {
  std::string hidden, label;
  bool right = false;
};

/// The verdict in one word: "none", the accepted effects joined by '+', or "ambiguous(a|b)".
std::string verdict_label(const rd::DiagnoseResult& res) {
  std::string acc;
  for (const auto& v : res.verdict) acc += (acc.empty() ? "" : "+") + v;
  if (!res.ambiguous.empty()) {
    std::string amb;
    for (const auto& a : res.ambiguous) amb += (amb.empty() ? "" : "|") + a;
    acc += (acc.empty() ? "" : "+") + ("ambiguous(" + amb + ")");
  }
  return acc.empty() ? "none" : acc;
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

Run run_one(const ig::Case& c, int seed, const Options& o) {
  ig::Settings st = c.settings;
  // The seeds of bench_diagnose indep (its rows stay comparable).
  st.seed = static_cast<std::uint64_t>(seed) * 104729u + 17u;
  st.duration_s = c.settings.hidden == ig::Hidden::kDampingDrift ? std::max(2.0, o.duration_s) : o.duration_s;
  st.sample_rate_hz = o.rate_hz;
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu0 = static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
  const auto rec = ig::generate(st);
  rm::RigParameters rig;  // the paper rig as a user describes it (config/rigs/paper-rig*.yaml)
  rig.crack_angle_rad = 1.0;
  rig.load_torque_n_m = st.load_torque_n_m;
  const auto seg = rd::subset_windows(rd::segment_recording(rec.y, o.rate_hz, rig), 16);
  const rd::ModelFitter fitter(rec.y, seg, rig);
  const auto res = rd::diagnose(fitter, {});
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double cpu = static_cast<double>(std::clock()) / CLOCKS_PER_SEC - cpu0;
  Run r;
  r.hidden = c.name;
  r.label = verdict_label(res);
  std::string want = c.name == "mesh_stiffness_variation+lines" ? "mesh_stiffness_variation" : c.name;
  if (c.name == "damping_step") want = "damping_drift";
  r.right = c.in_catalogue ? r.label == want : (res.verdict.empty() && res.ambiguous.empty() && res.unexplained);
  // A damping step is right only with its gap (the bracketing impacts contain the true time) and an
  // interval covering its size; a drift only without a step.
  const auto& ds = res.damping_step;
  if (c.name == "damping_step")
    r.right = r.right && ds.found && ds.time.ci95_lo < st.size2 && st.size2 < ds.time.ci95_hi && ds.step.ci95_lo < st.size &&
              st.size < ds.step.ci95_hi;
  if (c.name == "damping_drift") r.right = r.right && !ds.found;
  if (c.name == "none" && res.proposal.proposed) r.right = false;  // a control must not get a proposed force either
  std::printf("| %s | %d | %s | %s | %.3g -> %.3g | %s | %.0f / %.0f |\n", c.name.c_str(), seed, r.label.c_str(),
              res.unexplained ? "yes" : "no", res.baseline_excess, res.final_excess, r.right ? "yes" : "NO", wall, cpu);
  if (!r.right && !res.ambiguous_evidence.empty()) std::printf("|   | | ambiguous: %s | | | | |\n", res.ambiguous_evidence.c_str());
  if (res.proposal.proposed) std::printf("|   | | proposed: %s | | | | |\n", res.proposal.force.c_str());
  if (ds.found)
    std::printf("|   | | damping step %.4g (95 %%: %.4g .. %.4g) between the impacts at %.4g and %.4g s | | | | |\n", ds.step.value,
                ds.step.ci95_lo, ds.step.ci95_hi, ds.time.ci95_lo, ds.time.ci95_hi);
  std::fflush(stdout);
  return r;
}

void print_matrix(const std::vector<Run>& runs) {
  std::vector<std::string> rows, cols;
  for (const auto& r : runs) {
    if (std::find(rows.begin(), rows.end(), r.hidden) == rows.end()) rows.push_back(r.hidden);
    if (std::find(cols.begin(), cols.end(), r.label) == cols.end()) cols.push_back(r.label);
  }
  std::map<std::pair<std::string, std::string>, int> count;
  for (const auto& r : runs) ++count[{r.hidden, r.label}];
  std::printf("\nConfusion matrix (rows: hidden effect; columns: verdict; right = exactly the hidden effect)\n\n| hidden \\ verdict |");
  for (const auto& c : cols) std::printf(" %s |", c.c_str());
  std::printf(" right |\n|---|");
  for (std::size_t k = 0; k <= cols.size(); ++k) std::printf("---|");
  std::printf("\n");
  for (const auto& h : rows) {
    int n = 0, right = 0;
    for (const auto& r : runs)
      if (r.hidden == h) {
        ++n;
        right += r.right;
      }
    std::printf("| %s |", h.c_str());
    for (const auto& c : cols) {
      const auto it = count.find({h, c});
      if (it == count.end()) std::printf(" |");
      else std::printf(" %d |", it->second);
    }
    std::printf(" %d/%d |\n", right, n);
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (argc > 1) o.seeds = std::atoi(argv[1]);
  if (argc > 2) o.controls = std::atoi(argv[2]);
  if (argc > 3) o.duration_s = std::atof(argv[3]);
  if (argc > 4) o.rate_hz = std::atof(argv[4]);
  if (argc > 5) o.only = split(argv[5]);
  if (o.seeds < 0 || o.controls < 0 || o.duration_s < 0.3 || o.rate_hz < 8000.0) {
    std::fprintf(stderr, "usage: bench_diagnose_sweep [seeds] [controls] [duration_s >= 0.3] [rate_hz >= 8000] [case,...]\n");
    return 2;
  }
  std::printf("| hidden | seed | verdict | unexplained | held-out excess baseline -> final | right | wall / CPU s |\n|---|---|---|---|---|---|---|\n");
  std::vector<Run> runs;
  for (const auto& c : ig::sweep_cases()) {
    const bool named = std::find(o.only.begin(), o.only.end(), c.name) != o.only.end();
    if (o.only.empty() ? !c.in_catalogue : !named) continue;
    const int n = c.name == "none" ? o.controls : o.seeds;
    for (int seed = 1; seed <= n; ++seed) runs.push_back(run_one(c, seed, o));
  }
  print_matrix(runs);
  int false_alarms = 0, controls = 0, effect_runs = 0, effect_right = 0;
  for (const auto& r : runs) {
    if (r.hidden == "none") {
      ++controls;
      false_alarms += !r.right;
    } else {
      ++effect_runs;
      effect_right += r.right;
    }
  }
  std::printf("\nhidden effects named exactly: %d / %d; controls: %d false alarm(s) in %d\n", effect_right, effect_runs,
              false_alarms, controls);
  return 0;
}
