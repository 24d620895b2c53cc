// Bounded queue in front of a slow link, in lanes of FIFO streams: only the head of each stream
// competes, lowest priority key first and equal keys in arrival order, so a stream (one sender,
// one COB-ID, ...) never reorders while streams overtake each other. Each lane has its own bound
// and overflow rule; a push may replace the queued value of its stream (conflation). Pure,
// header-only; memory grows with what is queued (up to the bounds), not with the bounds, and is
// given back once the queue has drained after a large backlog.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <utility>
#include <vector>

namespace canbridge::backbone {

namespace detail {

// Open-addressing map from stream key to stream at load <= 1/2, doubling when it would pass it
// (std::unordered_map would allocate a node per queued item). It starts small: a lane bounded at
// 65,536 items mostly holds a handful of streams.
class StreamIndex {
 public:
  static constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
  static constexpr std::size_t kInitialBuckets = 16;

  StreamIndex() : buckets_(kInitialBuckets), mask_(kInitialBuckets - 1) {}

  std::uint32_t find(std::uint64_t key) const {
    for (std::size_t i = home(key);; i = (i + 1) & mask_) {
      if (buckets_[i].slot == kNone) return kNone;
      if (buckets_[i].key == key) return buckets_[i].slot;
    }
  }

  // Precondition: `key` is absent.
  void insert(std::uint64_t key, std::uint32_t slot) {
    if ((size_ + 1) * 2 > buckets_.size()) grow();
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
  std::size_t buckets() const { return buckets_.size(); }

  // Back to the initial size, freeing the buckets. Precondition: empty.
  void shrink() {
    std::vector<Bucket>(kInitialBuckets).swap(buckets_);
    mask_ = kInitialBuckets - 1;
  }

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

  void grow() {
    std::vector<Bucket> old(buckets_.size() * 2);
    old.swap(buckets_);
    mask_ = buckets_.size() - 1;
    size_ = 0;
    for (const Bucket& b : old) {
      if (b.slot != kNone) insert(b.key, b.slot);
    }
  }

  std::vector<Bucket> buckets_;
  std::size_t mask_;
  std::size_t size_ = 0;
};

}  // namespace detail

// Outcome of a push; outside the template so that it is one type for every Item.
enum class SchedulerPush {
  queued,     // a new entry in the queue
  displaced,  // a new entry, after the lane's oldest entry was dropped to make room
  conflated,  // replaced the value of the newest queued entry of its stream
  refused,    // the lane is full and refuses new entries
};

// What a full lane does with one more item.
enum class Overflow {
  refuse,       // the new item is refused (counted): for items that must not be lost silently
  drop_oldest,  // the lane's oldest item is dropped (counted): newer values matter more
};

// One lane's bound and overflow rule; outside the template, like SchedulerPush.
struct SchedulerLane {
  std::size_t max_items;
  Overflow overflow;
};

// Not thread-safe. Item needs only to be move-constructible and move-assignable.
template <class Item>
class PriorityScheduler {
 public:
  using Lane = SchedulerLane;

  using Push = SchedulerPush;

  struct Popped {
    Item item;
    std::size_t lane;
    std::uint32_t priority;
  };

  // What pop() would return, without popping it: a caller with a limited write budget (or a full
  // resend buffer, for reliable items) looks first and pops only what it can take.
  struct Front {
    const Item* item;  // valid until the next non-const call
    std::size_t lane;
    std::uint32_t priority;
  };

  // Per lane.
  struct Counters {
    std::uint64_t queued = 0;  // new entries (conflations not included)
    std::uint64_t conflated = 0;
    std::uint64_t dropped_oldest = 0;  // dropped to make room (Overflow::drop_oldest)
    std::uint64_t refused = 0;         // refused when full (Overflow::refuse, or a zero bound)
    std::uint64_t popped = 0;
  };

  // Once the queue drains, storage beyond this many items is given back: a burst that queued
  // 100,000 frames leaves an idle process small again, while a steady trickle does not
  // allocate and free on every wake.
  static constexpr std::size_t kKeptWhenIdle = 1024;

  // Allocates nothing for the items yet: storage grows as they are queued. Throws
  // std::invalid_argument when the limits together reach 2^32 - 1 items.
  explicit PriorityScheduler(std::vector<Lane> lanes) {
    std::size_t total = 0;
    for (const Lane& lane : lanes) {
      if (lane.max_items >= kNone - total) {
        throw std::invalid_argument("PriorityScheduler: limits too large");
      }
      total += lane.max_items;
    }
    lanes_.reserve(lanes.size());
    for (const Lane& lane : lanes) lanes_.emplace_back(lane);
  }

  // Queues `item` at the tail of stream `stream` of `lane`. It competes with the other streams'
  // heads once every earlier item of its stream has left, with `priority` (lower leaves first).
  // With `replace`, when the newest queued item of the stream was also pushed with `replace`, that
  // item takes the new value and keeps its place and priority instead (conflated). A full lane
  // refuses the item or drops its oldest item, by its overflow rule.
  Push push(std::size_t lane, std::uint64_t stream, std::uint32_t priority, bool replace,
            Item item) {
    LaneState& l = lanes_.at(lane);
    std::uint32_t s = l.index.find(stream);
    if (replace && s != kNone && slots_[streams_[s].tail].replaceable) {
      *slots_[streams_[s].tail].item = std::move(item);
      ++l.counters.conflated;
      return Push::conflated;
    }
    Push result = Push::queued;
    if (l.size >= l.options.max_items) {
      if (l.options.overflow == Overflow::refuse || l.size == 0) {
        ++l.counters.refused;
        return Push::refused;
      }
      (void)remove_head(slots_[l.oldest].stream);
      ++l.counters.dropped_oldest;
      s = l.index.find(stream);  // the drop may have emptied (and freed) this very stream
      result = Push::displaced;
    }
    const std::uint32_t slot_index = allocate_slot();
    Slot& slot = slots_[slot_index];
    slot.item.emplace(std::move(item));
    slot.arrival = next_arrival_++;
    slot.priority = priority;
    slot.replaceable = replace;
    slot.next_in_stream = kNone;
    slot.lane_newer = kNone;
    slot.lane_older = l.newest;
    if (l.newest != kNone) slots_[l.newest].lane_newer = slot_index;
    l.newest = slot_index;
    if (l.oldest == kNone) l.oldest = slot_index;
    ++l.size;
    ++l.counters.queued;
    if (s != kNone) {  // behind the stream's earlier items: the heap is unchanged
      slots_[streams_[s].tail].next_in_stream = slot_index;
      streams_[s].tail = slot_index;
      slot.stream = s;
      return result;
    }
    s = allocate_stream();
    streams_[s] = Stream{stream, static_cast<std::uint32_t>(lane), slot_index, slot_index,
                         static_cast<std::uint32_t>(heap_.size())};
    slot.stream = s;
    l.index.insert(stream, s);
    heap_.push_back(s);
    sift_up(streams_[s].heap_pos);
    return result;
  }

  // The item of stream `stream` in `lane` that leaves first (the oldest queued), or null when the
  // stream has none: how long it has waited tells whether the link keeps up with the stream.
  const Item* stream_head(std::size_t lane, std::uint64_t stream) const {
    const std::uint32_t s = lanes_.at(lane).index.find(stream);
    return s == kNone ? nullptr : &*slots_[streams_[s].head].item;
  }

  std::optional<Front> front() const {
    if (heap_.empty()) return std::nullopt;
    const Stream& stream = streams_[heap_.front()];
    const Slot& head = slots_[stream.head];
    return Front{&*head.item, stream.lane, head.priority};
  }

  // The head with the lowest priority, then the earliest arrival, across all lanes.
  std::optional<Popped> pop() {
    if (heap_.empty()) return std::nullopt;
    const std::uint32_t s = heap_.front();
    const std::size_t lane = streams_[s].lane;
    const std::uint32_t priority = slots_[streams_[s].head].priority;
    Popped popped{remove_head(s), lane, priority};
    ++lanes_[lane].counters.popped;
    if (heap_.empty()) release_storage_if_large();
    return popped;
  }

  // Removes every queued item `remove(item)` is true for, wherever it waits, and returns how many;
  // the others keep their streams, order and priorities. Linear in the items queued: for rare
  // events (a link went down), not for each item.
  template <class Predicate>
  std::size_t erase_if(Predicate remove) {
    std::size_t removed = 0;
    // Stream by stream, so that an item behind its head is unlinked in constant time; the heap is
    // rebuilt once afterwards.
    for (const std::uint32_t s : heap_) {
      Stream& stream = streams_[s];
      std::uint32_t kept = kNone;  // the last item of the stream that stays
      for (std::uint32_t i = stream.head; i != kNone;) {
        Slot& slot = slots_[i];
        const std::uint32_t next = slot.next_in_stream;
        if (remove(std::as_const(*slot.item))) {
          (kept == kNone ? stream.head : slots_[kept].next_in_stream) = next;
          release(i);
          ++removed;
        } else {
          kept = i;
        }
        i = next;
      }
      stream.tail = kept;
      if (kept == kNone) {
        lanes_[stream.lane].index.erase(stream.key);
        free_streams_.push_back(s);
      }
    }
    if (removed == 0) return 0;
    std::erase_if(heap_, [this](std::uint32_t s) { return streams_[s].tail == kNone; });
    for (std::size_t pos = 0; pos < heap_.size(); ++pos) move_in_heap(heap_[pos], pos);
    for (std::size_t pos = heap_.size() / 2; pos-- > 0;) sift_down(pos);
    if (heap_.empty()) release_storage_if_large();
    return removed;
  }

  std::size_t lane_size(std::size_t lane) const { return lanes_.at(lane).size; }
  std::size_t size() const { return slots_.size() - free_slots_.size(); }
  bool empty() const { return heap_.empty(); }
  // Streams with at least one item queued; never more than size().
  std::size_t stream_count() const { return heap_.size(); }
  const Counters& counters(std::size_t lane) const { return lanes_.at(lane).counters; }
  // Items the storage holds room for now (queued or not): grows with the backlog, never with
  // the bounds alone.
  std::size_t storage_items() const { return slots_.capacity(); }

 private:
  static constexpr std::uint32_t kNone = detail::StreamIndex::kNone;

  struct Slot {
    std::optional<Item> item;   // optional: Item need not be default-constructible
    std::uint64_t arrival = 0;  // strictly increasing: equal priorities leave in arrival order
    std::uint32_t priority = 0;
    std::uint32_t stream = kNone;
    std::uint32_t next_in_stream = kNone;
    // The lane's items in arrival order, so that the oldest can be dropped and any popped one
    // unlinked in constant time.
    std::uint32_t lane_older = kNone;
    std::uint32_t lane_newer = kNone;
    bool replaceable = false;
  };

  struct Stream {
    std::uint64_t key;
    std::uint32_t lane;
    std::uint32_t head;  // the only slot of the stream that competes in the heap
    std::uint32_t tail;
    std::uint32_t heap_pos;
  };

  struct LaneState {
    explicit LaneState(const Lane& lane) : options(lane) {}
    Lane options;
    detail::StreamIndex index;  // stream key -> stream, for the streams of this lane
    std::size_t size = 0;
    std::uint32_t oldest = kNone;
    std::uint32_t newest = kNone;
    Counters counters;
  };

  std::uint32_t allocate_slot() {
    if (free_slots_.empty()) {
      slots_.emplace_back();  // may reallocate: indices stay valid, references do not
      return static_cast<std::uint32_t>(slots_.size() - 1);
    }
    const std::uint32_t index = free_slots_.back();
    free_slots_.pop_back();
    return index;
  }

  std::uint32_t allocate_stream() {
    if (free_streams_.empty()) {
      streams_.emplace_back();
      return static_cast<std::uint32_t>(streams_.size() - 1);
    }
    const std::uint32_t index = free_streams_.back();
    free_streams_.pop_back();
    return index;
  }

  // Takes the head item out of stream `s`.
  Item remove_head(std::uint32_t s) {
    const std::uint32_t head = streams_[s].head;
    Item item = std::move(*slots_[head].item);
    unlink_head(s);
    return item;
  }

  // Frees the head of stream `s` (its item moved out already). The next item takes the stream's
  // place in the heap by its own priority and arrival; an emptied stream leaves the heap and the
  // index.
  void unlink_head(std::uint32_t s) {
    Stream& stream = streams_[s];
    const std::uint32_t head = stream.head;
    const std::uint32_t next = slots_[head].next_in_stream;
    release(head);
    if (next != kNone) {
      stream.head = next;
      restore_heap(stream.heap_pos);
      return;
    }
    lanes_[stream.lane].index.erase(stream.key);
    const std::uint32_t pos = stream.heap_pos;
    move_in_heap(heap_.back(), pos);
    heap_.pop_back();
    if (pos < heap_.size()) restore_heap(pos);
    free_streams_.push_back(s);
  }

  // Called with nothing queued: every slot and stream is free, so the pools can start over.
  void release_storage_if_large() {
    if (slots_.capacity() <= kKeptWhenIdle && streams_.capacity() <= kKeptWhenIdle) return;
    std::vector<Slot>().swap(slots_);
    std::vector<std::uint32_t>().swap(free_slots_);
    std::vector<Stream>().swap(streams_);
    std::vector<std::uint32_t>().swap(free_streams_);
    std::vector<std::uint32_t>().swap(heap_);
    for (LaneState& l : lanes_) l.index.shrink();
  }

  // Returns slot `index` to the pool, out of its lane's arrival order (not out of its stream).
  void release(std::uint32_t index) {
    Slot& slot = slots_[index];
    LaneState& l = lanes_[streams_[slot.stream].lane];
    slot.item.reset();
    (slot.lane_older == kNone ? l.oldest : slots_[slot.lane_older].lane_newer) = slot.lane_newer;
    (slot.lane_newer == kNone ? l.newest : slots_[slot.lane_newer].lane_older) = slot.lane_older;
    --l.size;
    free_slots_.push_back(index);
  }

  bool leaves_before(std::uint32_t a, std::uint32_t b) const {
    const Slot& x = slots_[streams_[a].head];
    const Slot& y = slots_[streams_[b].head];
    return x.priority != y.priority ? x.priority < y.priority : x.arrival < y.arrival;
  }

  void move_in_heap(std::uint32_t s, std::size_t pos) {
    heap_[pos] = s;
    streams_[s].heap_pos = static_cast<std::uint32_t>(pos);
  }

  // After the head of the stream at `pos` changed (or another stream took its place).
  void restore_heap(std::size_t pos) {
    const std::uint32_t s = heap_[pos];
    sift_up(pos);
    if (streams_[s].heap_pos == pos) sift_down(pos);
  }

  void sift_up(std::size_t pos) {
    const std::uint32_t s = heap_[pos];
    while (pos > 0) {
      const std::size_t parent = (pos - 1) / 2;
      if (!leaves_before(s, heap_[parent])) break;
      move_in_heap(heap_[parent], pos);
      pos = parent;
    }
    move_in_heap(s, pos);
  }

  void sift_down(std::size_t pos) {
    if (pos >= heap_.size()) return;
    const std::uint32_t s = heap_[pos];
    for (;;) {
      std::size_t child = 2 * pos + 1;
      if (child >= heap_.size()) break;
      if (child + 1 < heap_.size() && leaves_before(heap_[child + 1], heap_[child])) ++child;
      if (!leaves_before(heap_[child], s)) break;
      move_in_heap(heap_[child], pos);
      pos = child;
    }
    move_in_heap(s, pos);
  }

  std::vector<LaneState> lanes_;
  std::vector<Slot> slots_;  // pool; indices stay valid, freed ones are reused
  std::vector<std::uint32_t> free_slots_;
  std::vector<Stream> streams_;  // pool, like slots_
  std::vector<std::uint32_t> free_streams_;
  std::vector<std::uint32_t> heap_;  // streams by their head: (priority, arrival), min first
  std::uint64_t next_arrival_ = 0;
};

}  // namespace canbridge::backbone
