// OSMesa (llvmpipe) implementation of DepthRenderer. Fixed-function GL 1.x:
// each mesh is compiled once into a display list with face normals; one
// pass writes the label into red/green (material emission, exact bytes) and
// the Lambertian intensity into blue (a single light, blue only), and depth.
#include <GL/osmesa.h>
#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>

#include "pipeline/renderer.h"

namespace bp {
namespace {

// Eye coordinates of GL (y up, looking down -z) from the OpenCV camera frame C.
const Eigen::Matrix4d& GlFromCv() {
  static const Eigen::Matrix4d F = Eigen::Vector4d(1, -1, -1, 1).asDiagonal();
  return F;
}

// Projection for pinhole intrinsics. The window position of the ray through
// pixel (u, v) is (u + 0.5, H - (v + 0.5)): GL samples at pixel centres, and GL
// rows go bottom-up (rows are flipped on readback). See docs/synthetic.md.
Eigen::Matrix4d Projection(const Intrinsics& K, double n, double f) {
  const double W = K.width, H = K.height;
  Eigen::Matrix4d P = Eigen::Matrix4d::Zero();
  P(0, 0) = 2 * K.fx / W;
  P(0, 2) = 1 - 2 * (K.cx + 0.5) / W;
  P(1, 1) = 2 * K.fy / H;
  P(1, 2) = 2 * (K.cy + 0.5) / H - 1;
  P(2, 2) = -(f + n) / (f - n);
  P(2, 3) = -2 * f * n / (f - n);
  P(3, 2) = -1;
  return P;
}

class OsMesaRenderer final : public DepthRenderer {
 public:
  explicit OsMesaRenderer(OSMesaContext ctx) : ctx_(ctx) {}
  ~OsMesaRenderer() override {
    if (ctx_) {
      // Display lists die with the context.
      OSMesaDestroyContext(ctx_);
    }
  }

  Result<RenderOutput> Render(const RenderScene& scene, const Intrinsics& K,
                              const Pose& X_WC) override {
    RenderOutput out;
    if (Status s = RenderInto(scene, K, X_WC, out); !s.ok()) return s;
    return out;
  }

  Status RenderInto(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC,
                    RenderOutput& out) override {
    if (!K.valid()) return Status::InvalidArgument("render: invalid intrinsics");
    if (out.depth.width != K.width || out.depth.height != K.height) {
      out.depth = DepthImage(K.width, K.height);
      out.labels = LabelImage(K.width, K.height);
      out.intensity = IntensityImage(K.width, K.height);
    }
    return Draw(scene, K, X_WC, PixelRect{0, 0, K.width - 1, K.height - 1}, out);
  }

  Status RenderRegion(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC, const PixelRect& region,
                      RenderOutput& out) override {
    if (!K.valid()) return Status::InvalidArgument("render: invalid intrinsics");
    if (out.depth.width != K.width || out.depth.height != K.height || out.labels.width != K.width ||
        out.labels.height != K.height || out.intensity.width != K.width || out.intensity.height != K.height) {
      return Status::InvalidArgument("render: a region is rendered into an image of the intrinsics' size");
    }
    const PixelRect clipped{std::max(region.u0, 0), std::max(region.v0, 0), std::min(region.u1, K.width - 1),
                            std::min(region.v1, K.height - 1)};
    if (clipped.empty()) return Status::Ok();
    return Draw(scene, K, X_WC, clipped, out);
  }

 private:
  // Renders the scene and writes the pixels of `region` (inside the image,
  // not empty) into `out` (of K's size). Fragments outside `region` are
  // dropped by the scissor test; the clear, the draw and the readback cover
  // `region` only.
  Status Draw(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC, const PixelRect& region,
              RenderOutput& out) {
    if (!(scene.z_near > 0 && scene.z_far > scene.z_near)) {
      return Status::InvalidArgument("render: need 0 < z_near < z_far");
    }
    for (const auto& inst : scene.instances) {
      if (inst.mesh_index >= scene.meshes.size() || !scene.meshes[inst.mesh_index]) {
        return Status::InvalidArgument("render: instance refers to a missing mesh");
      }
    }
    const int w = K.width, h = K.height;
    const size_t n_px = static_cast<size_t>(w) * h;
    if (color_.size() < n_px * 4) color_.resize(n_px * 4);
    if (depth_.size() < n_px) depth_.resize(n_px);
    if (!OSMesaMakeCurrent(ctx_, color_.data(), GL_UNSIGNED_BYTE, w, h)) {
      return Status::Unavailable("render: OSMesaMakeCurrent failed");
    }
    // Unbind before returning. Mesa keeps the current context in a
    // thread-local; left bound, a thread that renders once (a request
    // handler) would still point at this context after another thread has
    // destroyed it, and its next OSMesaMakeCurrent flushes freed memory.
    struct Unbind {
      ~Unbind() { OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0); }
    } unbind;
    OSMesaPixelStore(OSMESA_Y_UP, 1);
    if (!configured_) Configure();

    // GL rows go bottom-up: image row v is GL row h - 1 - v.
    const int rw = region.u1 - region.u0 + 1, rh = region.v1 - region.v0 + 1;
    const int gl_y0 = h - 1 - region.v1;
    glViewport(0, 0, w, h);
    glEnable(GL_SCISSOR_TEST);
    glScissor(region.u0, gl_y0, rw, rh);
    glClearColor(0, 0, 0, 0);
    glClearDepth(1.0);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);

    glMatrixMode(GL_PROJECTION);
    const Eigen::Matrix4d P = Projection(K, scene.z_near, scene.z_far);
    glLoadMatrixd(P.data());

    glMatrixMode(GL_MODELVIEW);
    glLoadIdentity();
    const GLfloat light_pos[] = {static_cast<GLfloat>(scene.light_C.x()),
                                 static_cast<GLfloat>(-scene.light_C.y()),
                                 static_cast<GLfloat>(-scene.light_C.z()), 1.f};
    glLightfv(GL_LIGHT0, GL_POSITION, light_pos);
    const GLfloat amb = static_cast<GLfloat>(std::clamp(scene.ambient, 0.0, 1.0));
    const GLfloat global_ambient[] = {0.f, 0.f, amb, 1.f};
    glLightModelfv(GL_LIGHT_MODEL_AMBIENT, global_ambient);
    const GLfloat diffuse[] = {0.f, 0.f, 1.f - amb, 1.f};
    glLightfv(GL_LIGHT0, GL_DIFFUSE, diffuse);

    const Eigen::Matrix4d eye_from_W = GlFromCv() * X_WC.inverse().matrix();
    for (const auto& inst : scene.instances) {
      const GLuint list = MeshList(scene.meshes[inst.mesh_index]);
      if (list == 0) continue;
      const GLfloat emission[] = {static_cast<GLfloat>(inst.label & 0xFF) / 255.f,
                                  static_cast<GLfloat>(inst.label >> 8) / 255.f, 0.f, 1.f};
      glMaterialfv(GL_FRONT_AND_BACK, GL_EMISSION, emission);
      const Eigen::Matrix4d M = eye_from_W * inst.X_WO.matrix();
      glLoadMatrixd(M.data());
      glCallList(list);
    }
    // depth_ holds the region's rows bottom-up, rw floats each.
    glReadPixels(region.u0, gl_y0, rw, rh, GL_DEPTH_COMPONENT, GL_FLOAT, depth_.data());
    glFinish();
    glDisable(GL_SCISSOR_TEST);
    if (GLenum err = glGetError(); err != GL_NO_ERROR) {
      return Status::Internal("render: GL error " + std::to_string(err));
    }

    // Rows in parallel bands (oneTBB): each output pixel depends on its own
    // buffer pixel only, so the result does not depend on the schedule.
    const double n = scene.z_near, f = scene.z_far;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    tbb::parallel_for(tbb::blocked_range<int>(region.v0, region.v1 + 1, 64), [&](const tbb::blocked_range<int>& rows) {
      for (int v = rows.begin(); v < rows.end(); ++v) {
        const int r = h - 1 - v;  // GL rows are bottom-up
        const float* drow = depth_.data() + static_cast<size_t>(r - gl_y0) * rw;  // from u0
        const uint8_t* crow = color_.data() + static_cast<size_t>(r) * w * 4;
        float* zo = &out.depth.at(0, v);
        uint16_t* lo = &out.labels.at(0, v);
        uint8_t* io = &out.intensity.at(0, v);
        for (int u = region.u0; u <= region.u1; ++u) {
          const double d = drow[u - region.u0];
          if (d >= 1.0) {
            zo[u] = nan;
            lo[u] = 0;
            io[u] = 0;
            continue;
          }
          const double z_ndc = 2.0 * d - 1.0;
          zo[u] = static_cast<float>(2.0 * f * n / ((f + n) - z_ndc * (f - n)));
          lo[u] = static_cast<uint16_t>(crow[4 * u] | (crow[4 * u + 1] << 8));
          io[u] = crow[4 * u + 2];
        }
      }
    });
    return Status::Ok();
  }

  void Configure() {
    glDisable(GL_DITHER);
    glDisable(GL_BLEND);
    glDisable(GL_CULL_FACE);
    glDisable(GL_MULTISAMPLE);
    glDisable(GL_NORMALIZE);  // model matrices are rigid, normals stay unit
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glShadeModel(GL_SMOOTH);  // per-vertex lighting interpolated: no seams inside a planar face
    glEnable(GL_LIGHTING);
    glEnable(GL_LIGHT0);
    glLightModeli(GL_LIGHT_MODEL_TWO_SIDE, GL_TRUE);
    const GLfloat zero[] = {0.f, 0.f, 0.f, 1.f};
    const GLfloat one[] = {1.f, 1.f, 1.f, 1.f};
    glLightfv(GL_LIGHT0, GL_AMBIENT, zero);
    glLightfv(GL_LIGHT0, GL_SPECULAR, zero);
    glMaterialfv(GL_FRONT_AND_BACK, GL_AMBIENT, one);
    glMaterialfv(GL_FRONT_AND_BACK, GL_DIFFUSE, one);
    glMaterialfv(GL_FRONT_AND_BACK, GL_SPECULAR, zero);
    GLint depth_bits = 0;
    glGetIntegerv(GL_DEPTH_BITS, &depth_bits);
    spdlog::debug("osmesa renderer: {} depth bits, {}", depth_bits,
                  reinterpret_cast<const char*>(glGetString(GL_RENDERER)));
    configured_ = true;
  }

  // The display list of a mesh, compiled on first use.
  GLuint MeshList(const std::shared_ptr<const TriangleMesh>& mesh) {
    auto it = lists_.find(mesh.get());
    if (it != lists_.end()) return it->second.list;
    Cached c;
    c.mesh = mesh;
    if (!mesh->empty()) {
      c.list = glGenLists(1);
      glNewList(c.list, GL_COMPILE);
      glBegin(GL_TRIANGLES);
      const int nv = static_cast<int>(mesh->vertices.size());
      for (const auto& t : mesh->triangles) {
        if (t.minCoeff() < 0 || t.maxCoeff() >= nv) continue;
        const Eigen::Vector3f& a = mesh->vertices[t[0]];
        const Eigen::Vector3f& b = mesh->vertices[t[1]];
        const Eigen::Vector3f& cc = mesh->vertices[t[2]];
        Eigen::Vector3f nrm = (b - a).cross(cc - a);
        const float len = nrm.norm();
        if (len > 0) nrm /= len;
        // One face normal for all three vertices (faceted look).
        glNormal3f(nrm.x(), nrm.y(), nrm.z());
        glVertex3f(a.x(), a.y(), a.z());
        glVertex3f(b.x(), b.y(), b.z());
        glVertex3f(cc.x(), cc.y(), cc.z());
      }
      glEnd();
      glEndList();
    }
    lists_.emplace(mesh.get(), c);
    return c.list;
  }

  struct Cached {
    std::shared_ptr<const TriangleMesh> mesh;  // keeps the key address alive
    GLuint list = 0;
  };
  OSMesaContext ctx_ = nullptr;
  bool configured_ = false;
  std::vector<uint8_t> color_;  // RGBA, bottom-up, the OSMesa colour buffer
  std::vector<float> depth_;
  std::map<const TriangleMesh*, Cached> lists_;
};

}  // namespace

Result<std::unique_ptr<DepthRenderer>> MakeOsMesaRenderer() {
  OSMesaContext ctx = OSMesaCreateContextExt(OSMESA_RGBA, 32, 0, 0, nullptr);
  if (!ctx) ctx = OSMesaCreateContextExt(OSMESA_RGBA, 24, 0, 0, nullptr);
  if (!ctx) return Status::Unavailable("render: OSMesaCreateContextExt failed");
  return std::unique_ptr<DepthRenderer>(new OsMesaRenderer(ctx));
}

}  // namespace bp
