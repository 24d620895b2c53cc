// Bounded queue in front of a slow link: lowest priority key leaves first, equal keys in arrival
// order, reliable items are never dropped once queued, and process-data items may be conflated
// (a newer value replaces the queued one in place). Pure, header-only, no allocation after
// construction.
#pragma once

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <utility>
#include <vector>

namespace canbridge::backbone {

namespace detail {

// Open-addressing map from conflation key to slot, sized at construction for at most `capacity`
// entries at load <= 1/2, so it never rehashes or allocates (std::unordered_map would allocate a
// node per queued item).
class ConflationIndex {
 public:
  static constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

  explicit ConflationIndex(std::size_t capacity)
      : buckets_(std::bit_ceil(std::max<std::size_t>(capacity * 2, 2))),
        mask_(buckets_.size() - 1) {}

  std::uint32_t find(std::uint64_t key) const {
    for (std::size_t i = home(key);; i = (i + 1) & mask_) {
      if (buckets_[i].slot == kNone) return kNone;
      if (buckets_[i].key == key) return buckets_[i].slot;
    }
  }

  // Precondition: `key` is absent and fewer than `capacity` entries are present.
  void insert(std::uint64_t key, std::uint32_t slot) {
    std::size_t i = home(key);
    while (buckets_[i].slot != kNone) i = (i + 1) & mask_;
    buckets_[i] = Bucket{key, slot};
    ++size_;
  }

  // Backward-shift deletion: keeps every probe chain unbroken without tombstones, so lookups stay
  // short however long the scheduler runs.
  void erase(std::uint64_t key) {
    std::size_t hole = home(key);
    for (;; hole = (hole + 1) & mask_) {
      if (buckets_[hole].slot == kNone) return;  // absent
      if (buckets_[hole].key == key) break;
    }
    for (std::size_t next = (hole + 1) & mask_; buckets_[next].slot != kNone;
         next = (next + 1) & mask_) {
      const std::size_t next_home = home(buckets_[next].key);
      // `next` may fill the hole only if the hole lies on its probe path (home .. next).
      if (((next - next_home) & mask_) >= ((next - hole) & mask_)) {
        buckets_[hole] = buckets_[next];
        hole = next;
      }
    }
    buckets_[hole] = Bucket{};
    --size_;
  }

  std::size_t size() const { return size_; }

 private:
  struct Bucket {
    std::uint64_t key = 0;
    std::uint32_t slot = kNone;
  };

  // splitmix64 finalizer: keys are often dense small integers (module << 32 | id), which would
  // otherwise cluster into long probe runs.
  std::size_t home(std::uint64_t key) const {
    key ^= key >> 30;
    key *= 0xbf58476d1ce4e5b9ULL;
    key ^= key >> 27;
    key *= 0x94d049bb133111ebULL;
    key ^= key >> 31;
    return static_cast<std::size_t>(key) & mask_;
  }

  std::vector<Bucket> buckets_;
  std::size_t mask_;
  std::size_t size_ = 0;
};

}  // namespace detail

// Outcome of a push; outside the template so that it is one type for every Item.
enum class SchedulerPush {
  queued,     // a new entry in the queue
  conflated,  // replaced the value of the queued item with the same conflation key
  refused,    // queue full: a reliable item is refused, a process item dropped
};

// Not thread-safe. Item needs only to be move-constructible and move-assignable.
template <class Item>
class PriorityScheduler {
 public:
  struct Options {
    std::size_t max_reliable;  // reliable items queued at most
    std::size_t max_process;   // process-data items queued at most
  };

  using Push = SchedulerPush;

  struct Popped {
    Item item;
    bool reliable;
    std::uint32_t priority;
  };

  // What pop() would return, without popping it: a caller with a limited write budget (or a full
  // resend buffer, for reliable items) looks first and pops only what it can take.
  struct Front {
    const Item* item;  // valid until the next non-const call
    bool reliable;
    std::uint32_t priority;
  };

  struct Counters {
    std::uint64_t reliable_queued = 0;
    std::uint64_t reliable_refused = 0;
    std::uint64_t process_queued = 0;  // new process entries (conflations not included)
    std::uint64_t conflated = 0;
    std::uint64_t process_dropped = 0;  // process items dropped because their queue was full
    std::uint64_t popped = 0;
  };

  // Reserves everything the limits allow up front. Throws std::invalid_argument when the limits
  // together reach 2^32 - 1 items.
  explicit PriorityScheduler(Options options)
      : options_(validated(options)), index_(options_.max_process) {
    const std::size_t total = options_.max_reliable + options_.max_process;
    slots_.reserve(total);
    free_slots_.reserve(total);
    heap_.reserve(total);
  }

  // Queues a reliable item, or refuses it (counted) when max_reliable are queued: the caller must
  // treat that as a failure, since the item is not sent.
  Push push_reliable(std::uint32_t priority, Item item) {
    if (reliable_size_ >= options_.max_reliable) {
      ++counters_.reliable_refused;
      return Push::refused;
    }
    enqueue(priority, std::move(item), /*reliable=*/true, std::nullopt);
    ++reliable_size_;
    ++counters_.reliable_queued;
    return Push::queued;
  }

  // Queues a process-data item. With `conflate`, an item with the same `conflation_key` still
  // queued (not yet popped) takes the new value and keeps its place in the queue, and its priority
  // (the key is expected to determine the priority). Otherwise the item is queued, or dropped
  // (counted) when max_process are queued. Pushes with conflate == false are never conflated nor
  // conflated into.
  Push push_process(std::uint32_t priority, std::uint64_t conflation_key, bool conflate,
                    Item item) {
    if (conflate) {
      const std::uint32_t queued = index_.find(conflation_key);
      if (queued != detail::ConflationIndex::kNone) {
        *slots_[queued].item = std::move(item);
        ++counters_.conflated;
        return Push::conflated;
      }
    }
    if (process_size_ >= options_.max_process) {
      ++counters_.process_dropped;
      return Push::refused;
    }
    enqueue(priority, std::move(item), /*reliable=*/false,
            conflate ? std::optional<std::uint64_t>(conflation_key) : std::nullopt);
    ++process_size_;
    ++counters_.process_queued;
    return Push::queued;
  }

  std::optional<Front> front() const {
    if (heap_.empty()) return std::nullopt;
    const Slot& slot = slots_[heap_.front().slot];
    return Front{&*slot.item, slot.reliable, heap_.front().priority};
  }

  // Lowest priority first, then arrival order, across both classes.
  std::optional<Popped> pop() {
    if (heap_.empty()) return std::nullopt;
    std::pop_heap(heap_.begin(), heap_.end(), LeavesLater{});
    const HeapEntry top = heap_.back();
    heap_.pop_back();
    Slot& slot = slots_[top.slot];
    Popped popped{std::move(*slot.item), slot.reliable, top.priority};
    slot.item.reset();
    if (slot.conflation_key) index_.erase(*slot.conflation_key);
    (slot.reliable ? reliable_size_ : process_size_) -= 1;
    free_slots_.push_back(top.slot);
    ++counters_.popped;
    return popped;
  }

  std::size_t reliable_size() const { return reliable_size_; }
  std::size_t process_size() const { return process_size_; }
  std::size_t size() const { return heap_.size(); }
  bool empty() const { return heap_.empty(); }
  // Conflatable items currently queued; never more than process_size().
  std::size_t conflation_index_size() const { return index_.size(); }
  const Counters& counters() const { return counters_; }

 private:
  struct Slot {
    std::optional<Item> item;  // optional: Item need not be default-constructible
    bool reliable = false;
    std::optional<std::uint64_t> conflation_key;  // set while listed in the conflation index
  };

  struct HeapEntry {
    std::uint32_t priority;
    std::uint32_t slot;
    std::uint64_t arrival;  // strictly increasing: equal priorities leave in arrival order
  };

  // std heap algorithms build a max-heap; "greatest" must be what leaves first.
  struct LeavesLater {
    bool operator()(const HeapEntry& a, const HeapEntry& b) const {
      return a.priority != b.priority ? a.priority > b.priority : a.arrival > b.arrival;
    }
  };

  // Slot indices are 32-bit to keep heap entries small; kNone stays free as a sentinel.
  static Options validated(const Options& options) {
    constexpr std::size_t kMaxItems = detail::ConflationIndex::kNone;
    if (options.max_reliable >= kMaxItems ||
        options.max_process >= kMaxItems - options.max_reliable) {
      throw std::invalid_argument("PriorityScheduler: limits too large");
    }
    return options;
  }

  void enqueue(std::uint32_t priority, Item&& item, bool reliable,
               std::optional<std::uint64_t> conflation_key) {
    std::uint32_t slot_index;
    if (free_slots_.empty()) {
      slot_index = static_cast<std::uint32_t>(slots_.size());
      slots_.emplace_back();  // within the reservation: never reallocates
    } else {
      slot_index = free_slots_.back();
      free_slots_.pop_back();
    }
    Slot& slot = slots_[slot_index];
    slot.item.emplace(std::move(item));
    slot.reliable = reliable;
    slot.conflation_key = conflation_key;
    if (conflation_key) index_.insert(*conflation_key, slot_index);
    heap_.push_back(HeapEntry{priority, slot_index, next_arrival_++});
    std::push_heap(heap_.begin(), heap_.end(), LeavesLater{});
  }

  Options options_;
  detail::ConflationIndex index_;
  std::vector<Slot> slots_;  // pool; indices stay valid, freed ones are reused
  std::vector<std::uint32_t> free_slots_;
  std::vector<HeapEntry> heap_;
  std::size_t reliable_size_ = 0;
  std::size_t process_size_ = 0;
  std::uint64_t next_arrival_ = 0;
  Counters counters_;
};

}  // namespace canbridge::backbone
