// A process-wide memo of the model tables that are a function of their
// inputs alone (ClosestPointField::Build, PpfModel::Build): a build whose
// inputs match an earlier build's byte for byte copies that build's table
// instead of computing it again. Off unless a process turns it on
// (SetModelTableMemo): binpickd and the tools build each part's tables once,
// so the memo would only hold memory there. bp_pipeline_tests, which builds
// the same parts' models in many tests, turns it on (tests/testing/model_table_memo.cc):
// under ASan these two tables were about 40% of bp_pipeline_tests' CPU
// (docs/reliability.md, "Timings"). Private to bp_pipeline.
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

}  // namespace bp::internal
