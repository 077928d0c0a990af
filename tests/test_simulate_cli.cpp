// `ridgewatch simulate` end to end: files written, determinism, rig YAML errors -> exit 2 naming the key.
#include <gtest/gtest.h>
#include <sndfile.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "app/args.hpp"
#include "app/rig_yaml.hpp"
#include "core/model/effect_registry.hpp"

namespace fs = std::filesystem;

namespace {

const std::string kCli = RIDGEWATCH_CLI_PATH;
const std::string kPaperRig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";

struct CliRun {
  int exit_code;
  std::string out, err;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

class SimulateCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rw_sim_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  CliRun run(const std::string& args) {
    const std::string cmd = kCli + " simulate " + args + " >" + (dir_ / "stdout").string() + " 2>" + (dir_ / "stderr").string();
    const int status = std::system(cmd.c_str());
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(dir_ / "stdout"), slurp(dir_ / "stderr")};
  }

  std::string write_rig(const std::string& name, const std::string& text) {
    const fs::path p = dir_ / name;
    std::ofstream(p) << text;
    return p.string();
  }

  /// The paper rig with one line replaced (must exist).
  std::string paper_rig_with(const std::string& from, const std::string& to) {
    std::string text = slurp(kPaperRig);
    const auto pos = text.find(from);
    EXPECT_NE(pos, std::string::npos) << from;
    if (pos != std::string::npos) text.replace(pos, from.size(), to);
    return write_rig("rig.yaml", text);
  }

  fs::path dir_;
};

std::vector<float> read_wav(const std::string& path, SF_INFO& info) {
  info = {};
  SNDFILE* f = sf_open(path.c_str(), SFM_READ, &info);
  if (f == nullptr) return {};
  std::vector<float> data(static_cast<std::size_t>(info.frames * info.channels));
  sf_readf_float(f, data.data(), info.frames);
  sf_close(f);
  return data;
}

}  // namespace

TEST_F(SimulateCli, WritesWavAndTruthWithTacho) {
  const std::string base = (dir_ / "case").string();
  const CliRun r = run("--rig " + kPaperRig + " --duration 0.5 --channels vib,tacho --out " + base);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.out.empty());
  SF_INFO info;
  const auto data = read_wav(base + ".wav", info);
  ASSERT_EQ(info.channels, 2);
  EXPECT_EQ(info.samplerate, 51200);
  EXPECT_EQ(info.frames, 25600);
  EXPECT_EQ(info.format & SF_FORMAT_SUBMASK, SF_FORMAT_FLOAT);
  // Tacho: high at t = 0, 40, 80 ms...: 13 rising edges in 0.5 s (the first at sample 0).
  int edges = data[1] > 0.5f ? 1 : 0;
  for (std::size_t i = 1; i < static_cast<std::size_t>(info.frames); ++i)
    edges += (data[2 * i + 1] > 0.5f && data[2 * i - 1] <= 0.5f) ? 1 : 0;
  EXPECT_EQ(edges, 13);
  // Vibration: silent before the first impact (6.4 ms = sample 326), then the free response.
  EXPECT_EQ(data[2 * 300], 0.0f);
  float peak = 0.0f;
  for (std::size_t i = 0; i < static_cast<std::size_t>(info.frames); ++i) peak = std::max(peak, std::abs(data[2 * i]));
  EXPECT_GT(peak, 0.2f);  // impulse 0.19 N s / 27.5 kg × 0.914 × 50 ≈ 0.32 (±10 % jitter)
  EXPECT_LT(peak, 0.6f);
  const std::string truth = slurp(base + ".truth.json");
  EXPECT_NE(truth.find("\"f0_hz\":860.12"), std::string::npos);
  EXPECT_NE(truth.find("\"channels\":[\"vib\",\"tacho\"]"), std::string::npos);
  std::size_t impacts = 0;
  for (auto p = truth.find("\"peak_force_n\""); p != std::string::npos; p = truth.find("\"peak_force_n\"", p + 1)) ++impacts;
  EXPECT_EQ(impacts, 13u);
}

TEST_F(SimulateCli, SameSeedSameBytes) {
  const std::string common = "--rig " + kPaperRig +
                             " --duration 0.3 --noise 0.02 --effect coulomb_friction:force_n=20 --effect spikes --effect hum";
  ASSERT_EQ(run(common + " --seed 7 --out " + (dir_ / "a").string()).exit_code, 0);
  ASSERT_EQ(run(common + " --seed 7 --out " + (dir_ / "b").string()).exit_code, 0);
  ASSERT_EQ(run(common + " --seed 8 --out " + (dir_ / "c").string()).exit_code, 0);
  // Compare as booleans: a failure must not dump 60 kB of binary.
  EXPECT_TRUE(slurp(dir_ / "a.wav") == slurp(dir_ / "b.wav"));
  EXPECT_TRUE(slurp(dir_ / "a.truth.json") == slurp(dir_ / "b.truth.json"));
  EXPECT_FALSE(slurp(dir_ / "a.wav") == slurp(dir_ / "c.wav"));
  // Across a wall-clock second too (libsndfile's PEAK chunk would carry a timestamp).
  ::sleep(1);
  ASSERT_EQ(run(common + " --seed 7 --out " + (dir_ / "d").string()).exit_code, 0);
  EXPECT_TRUE(slurp(dir_ / "a.wav") == slurp(dir_ / "d.wav"));
  EXPECT_GT(slurp(dir_ / "a.wav").size(), 60000u);
}

TEST_F(SimulateCli, EffectsInTheRigFileAndOnTheCommandLine) {
  const std::string rig = paper_rig_with("  effects: []", "  effects:\n    - {name: coulomb_friction, force_n: 30}\n    - \"hum:amplitude_rel=0.1\"");
  const std::string base = (dir_ / "e").string();
  const CliRun r = run("--rig " + rig + " --duration 0.1 --effect coulomb_friction:force_n=40 --out " + base);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string truth = slurp(base + ".truth.json");
  EXPECT_NE(truth.find("\"force_n\":40"), std::string::npos);  // the command line wins
  EXPECT_EQ(truth.find("\"force_n\":30"), std::string::npos);
  EXPECT_NE(truth.find("\"amplitude_rel\":0.1"), std::string::npos);
}

TEST_F(SimulateCli, ListEffectsPrintsTheCatalogue) {
  const CliRun r = run("--list-effects");
  ASSERT_EQ(r.exit_code, 0);
  for (const auto& d : ridgewatch::model::effect_catalogue()) EXPECT_NE(r.out.find("\"" + d.name + "\""), std::string::npos) << d.name;
  EXPECT_GE(ridgewatch::model::effect_catalogue().size(), 12u);
}

TEST_F(SimulateCli, BadRigYamlExitsTwoNamingTheKey) {
  struct Case {
    std::string from, to, expected;
  };
  const std::vector<Case> cases = {
      {"  J1: 0.093 ", "  J1: -0.1 ", "gear.J1: must be > 0 (got -0.1)"},
      {"  J2: 0.272 ", "  J2: .nan ", "gear.J2: must be a finite number"},
      {"  rb1: 0.03046 ", "  rb1: thirty ", "gear.rb1: must be a number (got 'thirty')"},
      {"  c0: 8.04e8 ", "  c0_typo: 8.04e8 ", "mesh.c0_typo: unknown key"},
      {"  pinion_speed_rpm: 1500 ", "  # removed ", "operation.pinion_speed_rpm: missing"},
      {"  pinion_teeth: 22 ", "  pinion_teeth: 22.5 ", "gear.pinion_teeth: must be a whole number"},
      {"  damping_ratio: 0.024 ", "  damping_ratio: 0.024\n  d_z: 7000 ", "mesh.damping_ratio: give exactly one"},
      {"  effects: []", "  effects: [\"coulomb_friction:force_n=-5\"]", "model.effects[0]: effect coulomb_friction: force_n"},
      {"  effects: []", "  effects: [{name: no_such_effect}]", "model.effects[0]: unknown effect 'no_such_effect'"},
      {"  quantity: velocity ", "  quantity: jerk ", "sensor.quantity: must be velocity"},
      {"gear:  ", "gears: ", "gears: unknown key"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.to);
    const std::string rig = paper_rig_with(c.from, c.to);
    const CliRun r = run("--rig " + rig + " --duration 0.01 --out " + (dir_ / "x").string());
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find("rig.yaml: " + c.expected), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "x.wav"));
  }
  // Not YAML at all, and a missing file.
  const std::string broken = write_rig("broken.yaml", "gear: [unclosed\n");
  CliRun r = run("--rig " + broken + " --out " + (dir_ / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("broken.yaml: not valid YAML"), std::string::npos) << r.err;
  r = run("--rig " + (dir_ / "absent.yaml").string() + " --out " + (dir_ / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("absent.yaml: cannot open"), std::string::npos) << r.err;
}

TEST_F(SimulateCli, BadFlagsExitTwoNamingTheFlag) {
  const std::string out = " --out " + (dir_ / "x").string();
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--rig " + kPaperRig + " --effect warp_drive" + out, "--effect: unknown effect 'warp_drive'"},
      {"--rig " + kPaperRig + " --effect noise:sigma=1" + out, "--effect: effect noise: unknown parameter 'sigma'"},
      {"--rig " + kPaperRig + " --effect hum --effect hum" + out, "--effect: hum given twice"},
      {"--rig " + kPaperRig + " --channels vib,audio" + out, "--channels"},
      {"--rig " + kPaperRig + " --rate 44100.5" + out, "--rate"},
      {"--rig " + kPaperRig + " --noise 0.1 --effect noise" + out, "--noise"},
      {"--rig " + kPaperRig + " --duration -1" + out, "--duration"},
      {out, "--rig"},
      {"--rig " + kPaperRig, "--out"},
  };
  for (const auto& [args, expected] : cases) {
    SCOPED_TRACE(args);
    const CliRun r = run(args);
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
  }
}

TEST(RigYaml, PaperRigLoadsWithTheAppendixBValues) {
  const auto cfg = ridgewatch::app::load_rig_yaml(kPaperRig);
  EXPECT_DOUBLE_EQ(cfg.rig.pinion_inertia_kg_m2, 0.093);
  EXPECT_DOUBLE_EQ(cfg.rig.wheel_base_radius_m, 0.08466);
  ASSERT_EQ(cfg.rig.stiffness_harmonics.size(), 3u);
  EXPECT_DOUBLE_EQ(cfg.rig.stiffness_harmonics[2].phase_rad, -0.93);
  EXPECT_NEAR(cfg.rig.natural_frequency_hz(), 860.13, 0.01);  // ≈ 859 Hz in Appendix B (see test_model_rig)
  EXPECT_DOUBLE_EQ(cfg.rig.mesh_frequency_hz(), 550.0);
  EXPECT_TRUE(cfg.effects.empty());
  // d_z instead of ζ: the same rig.
  const std::string text = slurp(kPaperRig);
  std::string with_dz = text;
  with_dz.replace(with_dz.find("damping_ratio: 0.024"), 20, "d_z: 7140.935814889481");
  EXPECT_NEAR(ridgewatch::app::parse_rig_yaml(with_dz, "x.yaml").rig.damping_ratio, 0.024, 1e-12);
  EXPECT_THROW(ridgewatch::app::parse_rig_yaml("gear: {}", "x.yaml"), ridgewatch::app::UsageError);
}
