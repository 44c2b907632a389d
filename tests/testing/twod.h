// 2D task helpers: the shipped 2D cell and a calibration made the way RC
// 11/12 make it (the marker carried through the grid, seen by the camera).
#pragma once

#include <gtest/gtest.h>

#include <memory>

#include "core/cell.h"
#include "twod/detector_2d.h"
#include "twod/plane_calibration.h"
#include "twod/plane_camera.h"

namespace bp::testing {

inline Cell LoadTwodCell() {
  Result<Cell> cell = LoadCell(AssetsDir() + "/cells/twod.yaml");
  EXPECT_TRUE(cell.ok()) << cell.status().ToString();
  return cell.ok() ? *cell : Cell{};
}

// Marker at a grid of nx x ny points spanning span_x x span_y around the
// plane origin; @returns the fit.
inline Result<PlaneCalibration> CalibrateWithMarker(PlaneCamera& camera, int nx = 5, int ny = 4,
                                                    double span_x = 0.36, double span_y = 0.24) {
  std::vector<Eigen::Vector2d> pixels, plane;
  for (int iy = 0; iy < ny; ++iy) {
    for (int ix = 0; ix < nx; ++ix) {
      const Eigen::Vector2d xy(span_x * (static_cast<double>(ix) / (nx - 1) - 0.5),
                               span_y * (static_cast<double>(iy) / (ny - 1) - 0.5));
      PlaneCaptureRequest request;
      request.marker_X_PT = MakePose(Mat3::Identity(), Vec3(xy.x(), xy.y(), 0.0));
      Result<PlaneImage> image = camera.Capture(request);
      if (!image.ok()) return image.status();
      Result<Eigen::Vector2d> marker = FindMarker(image->image);
      if (!marker.ok()) return marker.status();
      pixels.push_back(*marker);
      plane.push_back(xy);
    }
  }
  return FitPlaneCalibration(camera.intrinsics(), pixels, plane);
}

}  // namespace bp::testing
