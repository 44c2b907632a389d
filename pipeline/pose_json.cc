#include "pipeline/pose_json.h"

namespace bp {

nlohmann::ordered_json PoseToJson(const Pose& X) {
  nlohmann::ordered_json rows = nlohmann::ordered_json::array();
  for (int r = 0; r < 4; ++r) {
    nlohmann::ordered_json row = nlohmann::ordered_json::array();
    for (int c = 0; c < 4; ++c) row.push_back(X.matrix()(r, c));
    rows.push_back(row);
  }
  return rows;
}

Result<Pose> PoseFromJson(const nlohmann::json& j, const std::string& what) {
  if (!j.is_array() || j.size() != 4) return Status::Corruption(what + " is not a 4x4 array");
  Eigen::Matrix4d M;
  for (size_t r = 0; r < 4; ++r) {
    const nlohmann::json& row = j[r];
    if (!row.is_array() || row.size() != 4) return Status::Corruption(what + " is not a 4x4 array");
    for (size_t c = 0; c < 4; ++c) {
      if (!row[c].is_number()) return Status::Corruption(what + " has a non-number");
      M(static_cast<int>(r), static_cast<int>(c)) = row[c].get<double>();
    }
  }
  if (!M.allFinite()) return Status::Corruption(what + " has non-finite entries");
  if (M.row(3) != Eigen::RowVector4d(0, 0, 0, 1)) return Status::Corruption(what + " last row is not [0, 0, 0, 1]");
  const Mat3 R = M.topLeftCorner<3, 3>();
  if (!(R.transpose() * R).isApprox(Mat3::Identity(), 1e-6) || R.determinant() < 0) {
    return Status::Corruption(what + " rotation is not orthonormal");
  }
  Pose X = Pose::Identity();
  X.matrix() = M;
  return X;
}

}  // namespace bp
