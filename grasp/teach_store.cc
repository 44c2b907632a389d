#include "grasp/teach_store.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

#include "core/atomic_file.h"

namespace bp {

TeachStore::TeachStore(std::string path, size_t max_per_class)
    : path_(std::move(path)), max_per_class_(max_per_class) {}

Status TeachStore::Load() {
  if (path_.empty() || !std::filesystem::exists(path_)) return Status::Ok();
  std::vector<TaughtGrasp> loaded;
  try {
    const YAML::Node root = YAML::LoadFile(path_);
    const YAML::Node list = root["grasps"];
    if (list.IsDefined() && !list.IsNull()) {
      if (!list.IsSequence()) return Status::Corruption(path_ + ": grasps: expected a list");
      for (size_t i = 0; i < list.size(); ++i) {
        const YAML::Node n = list[i];
        TaughtGrasp g;
        g.class_id = n["class_id"].as<int>();
        g.name = n["name"].as<std::string>();
        g.gripper = n["gripper"].as<std::string>();
        const auto xyz = n["pose"]["xyz"].as<std::vector<double>>();
        const auto q = n["pose"]["quat_wxyz"].as<std::vector<double>>();
        if (xyz.size() != 3 || q.size() != 4) {
          return Status::Corruption(path_ + ": grasps[" + std::to_string(i) + "].pose: need xyz[3] and quat_wxyz[4]");
        }
        g.X_OG = MakePose(Quat(q[0], q[1], q[2], q[3]), Vec3(xyz[0], xyz[1], xyz[2]));
        loaded.push_back(std::move(g));
      }
    }
  } catch (const YAML::Exception& e) {
    return Status::Corruption(path_ + ": " + e.what());
  }
  std::lock_guard lock(mutex_);
  grasps_ = std::move(loaded);
  return Status::Ok();
}

Status TeachStore::Add(TaughtGrasp grasp) {
  std::lock_guard lock(mutex_);
  const size_t same = static_cast<size_t>(std::count_if(
      grasps_.begin(), grasps_.end(), [&](const TaughtGrasp& g) {
        return g.class_id == grasp.class_id && g.gripper == grasp.gripper;
      }));
  if (same >= max_per_class_) {
    return Status::OutOfRange("class " + std::to_string(grasp.class_id) + " with gripper '" +
                              grasp.gripper + "' has " + std::to_string(same) +
                              " taught grasps already (the cap): not stored; remove some from '" +
                              (path_.empty() ? std::string("memory") : path_) + "' to teach more");
  }
  if (grasp.name.empty()) grasp.name = "taught_" + std::to_string(grasps_.size() + 1);
  grasps_.push_back(std::move(grasp));
  return WriteLocked();
}

std::vector<TaughtGrasp> TeachStore::All() const {
  std::lock_guard lock(mutex_);
  return grasps_;
}

Status TeachStore::WriteLocked() const {
  if (path_.empty()) return Status::Ok();
  std::ostringstream os;
  os << std::setprecision(17);
  os << "# binpick taught grasps (X_OG: tool centre point in the part frame)\ngrasps:\n";
  for (const TaughtGrasp& g : grasps_) {
    const Quat q(g.X_OG.linear());
    const Vec3 t = g.X_OG.translation();
    os << "  - {class_id: " << g.class_id << ", name: \"" << g.name << "\", gripper: \"" << g.gripper
       << "\", pose: {xyz: [" << t.x() << ", " << t.y() << ", " << t.z() << "], quat_wxyz: [" << q.w() << ", "
       << q.x() << ", " << q.y() << ", " << q.z() << "]}}\n";
  }
  AtomicWriteOptions w;
  w.mode = 0644;
  return WriteFileAtomic(path_, os.str(), w);
}

}  // namespace bp
