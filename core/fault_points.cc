#include "core/fault_points.h"

#include <atomic>
#include <map>
#include <mutex>
#include <new>
#include <string_view>

namespace bp::fault {
namespace {

struct Points {
  std::mutex mutex;
  std::map<std::string, int, std::less<>> hits;  // GUARDED_BY(mutex); left per point, > 0
  std::atomic<int> armed{0};                     // points in `hits`: Hit's fast path
};

Points& ThePoints() {
  static Points* points = new Points;  // never destroyed: Hit may run during exit
  return *points;
}

}  // namespace

void Hit(const char* point) {
  Points& p = ThePoints();
  if (p.armed.load(std::memory_order_relaxed) == 0) return;
  {
    std::lock_guard lock(p.mutex);
    auto it = p.hits.find(std::string_view(point));
    if (it == p.hits.end()) return;
    if (--it->second == 0) {
      p.hits.erase(it);
      p.armed.fetch_sub(1, std::memory_order_relaxed);
    }
  }
  throw std::bad_alloc();
}

void Arm(const std::string& point, int hits) {
  if (hits <= 0) return;
  Points& p = ThePoints();
  std::lock_guard lock(p.mutex);
  auto [it, added] = p.hits.emplace(point, 0);
  it->second += hits;
  if (added) p.armed.fetch_add(1, std::memory_order_relaxed);
}

int Armed(const std::string& point) {
  Points& p = ThePoints();
  std::lock_guard lock(p.mutex);
  auto it = p.hits.find(point);
  return it == p.hits.end() ? 0 : it->second;
}

void DisarmAll() {
  Points& p = ThePoints();
  std::lock_guard lock(p.mutex);
  p.hits.clear();
  p.armed.store(0, std::memory_order_relaxed);
}

}  // namespace bp::fault
