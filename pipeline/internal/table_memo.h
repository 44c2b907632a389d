// A process-wide memo of the model tables that are a function of their
// inputs alone (ClosestPointField::Build, PpfModel::Build, and the model
// geometry both the pose estimator and grasp planning build: SampleSurface,
// PointSetDiameter, ExtremePoints, BuildEdgePlanes): a build whose
// inputs match an earlier build's byte for byte copies that build's table
// instead of computing it again. Off unless a process turns it on
// (SetModelTableMemo): binpickd and the tools build each part's tables once,
// so the memo would only hold memory there. bp_pipeline_tests and
// bp_grasp_tests, which build the same parts' models in many tests, turn it
// on (tests/testing/model_table_memo.cc): under ASan the first two tables
// were about 40% of bp_pipeline_tests' CPU, the geometry 15% of it and 8% of
// bp_grasp_tests' (docs/reliability.md, "Timings"). Private to bp_pipeline.
#pragma once

#include <cstddef>
#include <cstring>
#include <deque>
#include <mutex>
#include <span>
#include <string>
#include <type_traits>
#include <utility>

namespace bp::internal {

// Turns the memo on or off for the whole process (off by default). Turning
// it off drops nothing: tables stored stay for when it is on again.
void SetModelTableMemo(bool on);
bool ModelTableMemoOn();
// How many builds were copied from the memo so far (for tests).
size_t ModelTableMemoHits();
void CountModelTableMemoHit();

// A build's inputs as bytes: each value or span appended with its size, so
// that two different argument lists never give the same key. The values are
// read as bytes: plain numbers or fixed-size Eigen vectors without padding.
class TableMemoKey {
 public:
  template <class T>
  TableMemoKey& Add(const T& value) {
    static_assert(std::is_trivially_copyable_v<T>);
    return AddBytes(&value, sizeof(T));
  }
  template <class T>
  TableMemoKey& AddSpan(std::span<const T> values) {
    Add(values.size());
    return AddBytes(values.data(), values.size_bytes());
  }
  const std::string& bytes() const { return bytes_; }

 private:
  TableMemoKey& AddBytes(const void* data, size_t size) {
    bytes_.append(static_cast<const char*>(data), size);
    return *this;
  }
  std::string bytes_;
};

// The tables of one kind built so far, by key: the newest kMaxEntries (the
// oldest is dropped first). Thread-safe; Table must be copyable.
template <class Table>
class TableMemo {
 public:
  static constexpr size_t kMaxEntries = 32;
  // Copies the table stored under `key` into *table; false when there is none.
  bool Find(const TableMemoKey& key, Table* table) const {
    std::lock_guard lock(mu_);
    for (const auto& [k, t] : entries_) {
      if (k == key.bytes()) {
        *table = t;
        CountModelTableMemoHit();
        return true;
      }
    }
    return false;
  }
  void Store(const TableMemoKey& key, const Table& table) {
    std::lock_guard lock(mu_);
    for (const auto& entry : entries_) {
      if (entry.first == key.bytes()) return;  // built by two threads at once
    }
    if (entries_.size() == kMaxEntries) entries_.pop_front();
    entries_.emplace_back(key.bytes(), table);
  }

 private:
  mutable std::mutex mu_;
  std::deque<std::pair<std::string, Table>> entries_;
};

// compute() with the memo off; with it on, the copy of what an earlier call
// under the same key stored, else compute()'s result, stored. `compute` must
// be a function of what `key` holds alone.
template <class Table, class Compute>
Table Memoised(TableMemo<Table>& memo, const TableMemoKey& key, Compute&& compute) {
  Table table;
  if (memo.Find(key, &table)) return table;
  table = compute();
  memo.Store(key, table);
  return table;
}

}  // namespace bp::internal
