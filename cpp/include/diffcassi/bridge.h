#pragma once
#include <algorithm>
#include <array>
#include <cassert>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <iterator>
#include <new>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#if __cplusplus >= 201703L
#include <string_view>
#endif
#if __cplusplus >= 202002L
#include <ranges>
#endif

#ifdef __clang__
#pragma clang diagnostic push
#pragma clang diagnostic ignored "-Wdollar-in-identifier-extension"
#endif // __clang__

namespace rust {
inline namespace cxxbridge1 {
// #include "rust/cxx.h"

#ifndef CXXBRIDGE1_PANIC
#define CXXBRIDGE1_PANIC
template <typename Exception>
void panic [[noreturn]] (const char *msg);
#endif // CXXBRIDGE1_PANIC

struct unsafe_bitcopy_t;

namespace {
template <typename T>
class impl;
} // namespace

template <typename T>
::std::size_t size_of();
template <typename T>
::std::size_t align_of();

#ifndef CXXBRIDGE1_RUST_STRING
#define CXXBRIDGE1_RUST_STRING
class String final {
public:
  String() noexcept;
  String(const String &) noexcept;
  String(String &&) noexcept;
  ~String() noexcept;

  String(const std::string &);
  String(const char *);
  String(const char *, std::size_t);
  String(const char16_t *);
  String(const char16_t *, std::size_t);
#ifdef __cpp_char8_t
  String(const char8_t *s);
  String(const char8_t *s, std::size_t len);
#endif

  static String lossy(const std::string &) noexcept;
  static String lossy(const char *) noexcept;
  static String lossy(const char *, std::size_t) noexcept;
  static String lossy(const char16_t *) noexcept;
  static String lossy(const char16_t *, std::size_t) noexcept;

  String &operator=(const String &) & noexcept;
  String &operator=(String &&) & noexcept;

  explicit operator std::string() const;

  const char *data() const noexcept;
  char *data() noexcept;

  std::size_t size() const noexcept;
  std::size_t length() const noexcept;
  bool empty() const noexcept;

  const char *c_str() noexcept;

  std::size_t capacity() const noexcept;
  void reserve(size_t new_cap) noexcept;

  using iterator = char *;
  iterator begin() noexcept;
  iterator end() noexcept;

  using const_iterator = const char *;
  const_iterator begin() const noexcept;
  const_iterator end() const noexcept;
  const_iterator cbegin() const noexcept;
  const_iterator cend() const noexcept;

  bool operator==(const String &) const noexcept;
  bool operator!=(const String &) const noexcept;
  bool operator<(const String &) const noexcept;
  bool operator<=(const String &) const noexcept;
  bool operator>(const String &) const noexcept;
  bool operator>=(const String &) const noexcept;

  void swap(String &) noexcept;

  String(unsafe_bitcopy_t, const String &) noexcept;

private:
  struct lossy_t;
  String(lossy_t, const char *, std::size_t) noexcept;
  String(lossy_t, const char16_t *, std::size_t) noexcept;
  friend void swap(String &lhs, String &rhs) noexcept { lhs.swap(rhs); }

  std::array<std::uintptr_t, 3> repr;
};
#endif // CXXBRIDGE1_RUST_STRING

#ifndef CXXBRIDGE1_RUST_STR
#define CXXBRIDGE1_RUST_STR
class Str final {
public:
  Str() noexcept;
  Str(const String &) noexcept;
  Str(const std::string &);
  Str(const char *);
  Str(const char *, std::size_t);

  Str &operator=(const Str &) & noexcept = default;

  explicit operator std::string() const;
#if __cplusplus >= 201703L
  explicit operator std::string_view() const;
#endif

  const char *data() const noexcept;
  std::size_t size() const noexcept;
  std::size_t length() const noexcept;
  bool empty() const noexcept;

  Str(const Str &) noexcept = default;
  ~Str() noexcept = default;

  using iterator = const char *;
  using const_iterator = const char *;
  const_iterator begin() const noexcept;
  const_iterator end() const noexcept;
  const_iterator cbegin() const noexcept;
  const_iterator cend() const noexcept;

  bool operator==(const Str &) const noexcept;
  bool operator!=(const Str &) const noexcept;
  bool operator<(const Str &) const noexcept;
  bool operator<=(const Str &) const noexcept;
  bool operator>(const Str &) const noexcept;
  bool operator>=(const Str &) const noexcept;

  void swap(Str &) noexcept;

private:
  class uninit;
  Str(uninit) noexcept;
  friend impl<Str>;

  std::array<std::uintptr_t, 2> repr;
};
#endif // CXXBRIDGE1_RUST_STR

#ifndef CXXBRIDGE1_RUST_SLICE
#define CXXBRIDGE1_RUST_SLICE
namespace detail {
template <bool>
struct copy_assignable_if {};

template <>
struct copy_assignable_if<false> {
  copy_assignable_if() noexcept = default;
  copy_assignable_if(const copy_assignable_if &) noexcept = default;
  copy_assignable_if &operator=(const copy_assignable_if &) & noexcept = delete;
  copy_assignable_if &operator=(copy_assignable_if &&) & noexcept = default;
};
} // namespace detail

template <typename T>
class Slice final
    : private detail::copy_assignable_if<std::is_const<T>::value> {
public:
  using value_type = T;

  Slice() noexcept;
  Slice(T *, std::size_t count) noexcept;

  template <typename C>
  explicit Slice(C &c) : Slice(c.data(), c.size()) {}

  Slice &operator=(const Slice<T> &) & noexcept = default;
  Slice &operator=(Slice<T> &&) & noexcept = default;

  T *data() const noexcept;
  std::size_t size() const noexcept;
  std::size_t length() const noexcept;
  bool empty() const noexcept;

  T &operator[](std::size_t n) const noexcept;
  T &at(std::size_t n) const;
  T &front() const noexcept;
  T &back() const noexcept;

  Slice(const Slice<T> &) noexcept = default;
  ~Slice() noexcept = default;

  class iterator;
  iterator begin() const noexcept;
  iterator end() const noexcept;

  void swap(Slice &) noexcept;

private:
  class uninit;
  Slice(uninit) noexcept;
  friend impl<Slice>;
  friend void sliceInit(void *, const void *, std::size_t) noexcept;
  friend void *slicePtr(const void *) noexcept;
  friend std::size_t sliceLen(const void *) noexcept;

  std::array<std::uintptr_t, 2> repr;
};

#ifdef __cpp_deduction_guides
template <typename C>
explicit Slice(C &c)
    -> Slice<std::remove_reference_t<decltype(*std::declval<C>().data())>>;
#endif // __cpp_deduction_guides

template <typename T>
class Slice<T>::iterator final {
public:
#if __cplusplus >= 202002L
  using iterator_category = std::contiguous_iterator_tag;
#else
  using iterator_category = std::random_access_iterator_tag;
#endif
  using value_type = T;
  using difference_type = std::ptrdiff_t;
  using pointer = typename std::add_pointer<T>::type;
  using reference = typename std::add_lvalue_reference<T>::type;

  reference operator*() const noexcept;
  pointer operator->() const noexcept;
  reference operator[](difference_type) const noexcept;

  iterator &operator++() noexcept;
  iterator operator++(int) noexcept;
  iterator &operator--() noexcept;
  iterator operator--(int) noexcept;

  iterator &operator+=(difference_type) noexcept;
  iterator &operator-=(difference_type) noexcept;
  iterator operator+(difference_type) const noexcept;
  friend inline iterator operator+(difference_type lhs, iterator rhs) noexcept {
    return rhs + lhs;
  }
  iterator operator-(difference_type) const noexcept;
  difference_type operator-(const iterator &) const noexcept;

  bool operator==(const iterator &) const noexcept;
  bool operator!=(const iterator &) const noexcept;
  bool operator<(const iterator &) const noexcept;
  bool operator<=(const iterator &) const noexcept;
  bool operator>(const iterator &) const noexcept;
  bool operator>=(const iterator &) const noexcept;

private:
  friend class Slice;
  void *pos;
  std::size_t stride;
};

template <typename T>
Slice<T>::Slice() noexcept {
  sliceInit(this, reinterpret_cast<void *>(align_of<T>()), 0);
}

template <typename T>
Slice<T>::Slice(T *s, std::size_t count) noexcept {
  assert(s != nullptr || count == 0);
  sliceInit(this,
            s == nullptr && count == 0
                ? reinterpret_cast<void *>(align_of<T>())
                : const_cast<typename std::remove_const<T>::type *>(s),
            count);
}

template <typename T>
T *Slice<T>::data() const noexcept {
  return reinterpret_cast<T *>(slicePtr(this));
}

template <typename T>
std::size_t Slice<T>::size() const noexcept {
  return sliceLen(this);
}

template <typename T>
std::size_t Slice<T>::length() const noexcept {
  return this->size();
}

template <typename T>
bool Slice<T>::empty() const noexcept {
  return this->size() == 0;
}

template <typename T>
T &Slice<T>::operator[](std::size_t n) const noexcept {
  assert(n < this->size());
  auto ptr = static_cast<char *>(slicePtr(this)) + size_of<T>() * n;
  return *reinterpret_cast<T *>(ptr);
}

template <typename T>
T &Slice<T>::at(std::size_t n) const {
  if (n >= this->size()) {
    panic<std::out_of_range>("rust::Slice index out of range");
  }
  return (*this)[n];
}

template <typename T>
T &Slice<T>::front() const noexcept {
  assert(!this->empty());
  return (*this)[0];
}

template <typename T>
T &Slice<T>::back() const noexcept {
  assert(!this->empty());
  return (*this)[this->size() - 1];
}

template <typename T>
typename Slice<T>::iterator::reference
Slice<T>::iterator::operator*() const noexcept {
  return *static_cast<T *>(this->pos);
}

template <typename T>
typename Slice<T>::iterator::pointer
Slice<T>::iterator::operator->() const noexcept {
  return static_cast<T *>(this->pos);
}

template <typename T>
typename Slice<T>::iterator::reference Slice<T>::iterator::operator[](
    typename Slice<T>::iterator::difference_type n) const noexcept {
  auto ptr = static_cast<char *>(this->pos) + this->stride * n;
  return *reinterpret_cast<T *>(ptr);
}

template <typename T>
typename Slice<T>::iterator &Slice<T>::iterator::operator++() noexcept {
  this->pos = static_cast<char *>(this->pos) + this->stride;
  return *this;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::iterator::operator++(int) noexcept {
  auto ret = iterator(*this);
  this->pos = static_cast<char *>(this->pos) + this->stride;
  return ret;
}

template <typename T>
typename Slice<T>::iterator &Slice<T>::iterator::operator--() noexcept {
  this->pos = static_cast<char *>(this->pos) - this->stride;
  return *this;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::iterator::operator--(int) noexcept {
  auto ret = iterator(*this);
  this->pos = static_cast<char *>(this->pos) - this->stride;
  return ret;
}

template <typename T>
typename Slice<T>::iterator &Slice<T>::iterator::operator+=(
    typename Slice<T>::iterator::difference_type n) noexcept {
  this->pos = static_cast<char *>(this->pos) + this->stride * n;
  return *this;
}

template <typename T>
typename Slice<T>::iterator &Slice<T>::iterator::operator-=(
    typename Slice<T>::iterator::difference_type n) noexcept {
  this->pos = static_cast<char *>(this->pos) - this->stride * n;
  return *this;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::iterator::operator+(
    typename Slice<T>::iterator::difference_type n) const noexcept {
  auto ret = iterator(*this);
  ret.pos = static_cast<char *>(this->pos) + this->stride * n;
  return ret;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::iterator::operator-(
    typename Slice<T>::iterator::difference_type n) const noexcept {
  auto ret = iterator(*this);
  ret.pos = static_cast<char *>(this->pos) - this->stride * n;
  return ret;
}

template <typename T>
typename Slice<T>::iterator::difference_type
Slice<T>::iterator::operator-(const iterator &other) const noexcept {
  auto diff = std::distance(static_cast<char *>(other.pos),
                            static_cast<char *>(this->pos));
  return diff / static_cast<typename Slice<T>::iterator::difference_type>(
                    this->stride);
}

template <typename T>
bool Slice<T>::iterator::operator==(const iterator &other) const noexcept {
  return this->pos == other.pos;
}

template <typename T>
bool Slice<T>::iterator::operator!=(const iterator &other) const noexcept {
  return this->pos != other.pos;
}

template <typename T>
bool Slice<T>::iterator::operator<(const iterator &other) const noexcept {
  return this->pos < other.pos;
}

template <typename T>
bool Slice<T>::iterator::operator<=(const iterator &other) const noexcept {
  return this->pos <= other.pos;
}

template <typename T>
bool Slice<T>::iterator::operator>(const iterator &other) const noexcept {
  return this->pos > other.pos;
}

template <typename T>
bool Slice<T>::iterator::operator>=(const iterator &other) const noexcept {
  return this->pos >= other.pos;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::begin() const noexcept {
  iterator it;
  it.pos = slicePtr(this);
  it.stride = size_of<T>();
  return it;
}

template <typename T>
typename Slice<T>::iterator Slice<T>::end() const noexcept {
  iterator it = this->begin();
  it.pos = static_cast<char *>(it.pos) + it.stride * this->size();
  return it;
}

template <typename T>
void Slice<T>::swap(Slice &rhs) noexcept {
  std::swap(*this, rhs);
}
#endif // CXXBRIDGE1_RUST_SLICE

#ifndef CXXBRIDGE1_RUST_BOX
#define CXXBRIDGE1_RUST_BOX
template <typename T>
class Box final {
public:
  using element_type = T;
  using const_pointer =
      typename std::add_pointer<typename std::add_const<T>::type>::type;
  using pointer = typename std::add_pointer<T>::type;

  Box() = delete;
  Box(Box &&) noexcept;
  ~Box() noexcept;

  explicit Box(const T &);
  explicit Box(T &&);

  Box &operator=(Box &&) & noexcept;

  const T *operator->() const noexcept;
  const T &operator*() const noexcept;
  T *operator->() noexcept;
  T &operator*() noexcept;

  template <typename... Fields>
  static Box in_place(Fields &&...);

  void swap(Box &) noexcept;

  static Box from_raw(T *) noexcept;

  T *into_raw() noexcept;

  /* Deprecated */ using value_type = element_type;

private:
  class uninit;
  class allocation;
  Box(uninit) noexcept;
  void drop() noexcept;

  friend void swap(Box &lhs, Box &rhs) noexcept { lhs.swap(rhs); }

  T *ptr;
};

template <typename T>
class Box<T>::uninit {};

template <typename T>
class Box<T>::allocation {
  static T *alloc() noexcept;
  static void dealloc(T *) noexcept;

public:
  allocation() noexcept : ptr(alloc()) {}
  ~allocation() noexcept {
    if (this->ptr) {
      dealloc(this->ptr);
    }
  }
  T *ptr;
};

template <typename T>
Box<T>::Box(Box &&other) noexcept : ptr(other.ptr) {
  other.ptr = nullptr;
}

template <typename T>
Box<T>::Box(const T &val) {
  allocation alloc;
  ::new (alloc.ptr) T(val);
  this->ptr = alloc.ptr;
  alloc.ptr = nullptr;
}

template <typename T>
Box<T>::Box(T &&val) {
  allocation alloc;
  ::new (alloc.ptr) T(std::move(val));
  this->ptr = alloc.ptr;
  alloc.ptr = nullptr;
}

template <typename T>
Box<T>::~Box() noexcept {
  if (this->ptr) {
    this->drop();
  }
}

template <typename T>
Box<T> &Box<T>::operator=(Box &&other) & noexcept {
  if (this->ptr) {
    this->drop();
  }
  this->ptr = other.ptr;
  other.ptr = nullptr;
  return *this;
}

template <typename T>
const T *Box<T>::operator->() const noexcept {
  return this->ptr;
}

template <typename T>
const T &Box<T>::operator*() const noexcept {
  return *this->ptr;
}

template <typename T>
T *Box<T>::operator->() noexcept {
  return this->ptr;
}

template <typename T>
T &Box<T>::operator*() noexcept {
  return *this->ptr;
}

template <typename T>
template <typename... Fields>
Box<T> Box<T>::in_place(Fields &&...fields) {
  allocation alloc;
  auto ptr = alloc.ptr;
  ::new (ptr) T{std::forward<Fields>(fields)...};
  alloc.ptr = nullptr;
  return from_raw(ptr);
}

template <typename T>
void Box<T>::swap(Box &rhs) noexcept {
  using std::swap;
  swap(this->ptr, rhs.ptr);
}

template <typename T>
Box<T> Box<T>::from_raw(T *raw) noexcept {
  Box box = uninit{};
  box.ptr = raw;
  return box;
}

template <typename T>
T *Box<T>::into_raw() noexcept {
  T *raw = this->ptr;
  this->ptr = nullptr;
  return raw;
}

template <typename T>
Box<T>::Box(uninit) noexcept {}
#endif // CXXBRIDGE1_RUST_BOX

#ifndef CXXBRIDGE1_RUST_BITCOPY_T
#define CXXBRIDGE1_RUST_BITCOPY_T
struct unsafe_bitcopy_t final {
  explicit unsafe_bitcopy_t() = default;
};
#endif // CXXBRIDGE1_RUST_BITCOPY_T

#ifndef CXXBRIDGE1_RUST_VEC
#define CXXBRIDGE1_RUST_VEC
template <typename T>
class Vec final {
public:
  using value_type = T;

  Vec() noexcept;
  Vec(std::initializer_list<T>);
  Vec(const Vec &);
  Vec(Vec &&) noexcept;
  ~Vec() noexcept;

  Vec &operator=(Vec &&) & noexcept;
  Vec &operator=(const Vec &) &;

  std::size_t size() const noexcept;
  bool empty() const noexcept;
  const T *data() const noexcept;
  T *data() noexcept;
  std::size_t capacity() const noexcept;

  const T &operator[](std::size_t n) const noexcept;
  const T &at(std::size_t n) const;
  const T &front() const noexcept;
  const T &back() const noexcept;

  T &operator[](std::size_t n) noexcept;
  T &at(std::size_t n);
  T &front() noexcept;
  T &back() noexcept;

  void reserve(std::size_t new_cap);
  void push_back(const T &value);
  void push_back(T &&value);
  template <typename... Args>
  void emplace_back(Args &&...args);
  void truncate(std::size_t len);
  void clear();

  using iterator = typename Slice<T>::iterator;
  iterator begin() noexcept;
  iterator end() noexcept;

  using const_iterator = typename Slice<const T>::iterator;
  const_iterator begin() const noexcept;
  const_iterator end() const noexcept;
  const_iterator cbegin() const noexcept;
  const_iterator cend() const noexcept;

  void swap(Vec &) noexcept;

  Vec(unsafe_bitcopy_t, const Vec &) noexcept;

private:
  void reserve_total(std::size_t new_cap) noexcept;
  void set_len(std::size_t len) noexcept;
  void drop() noexcept;

  friend void swap(Vec &lhs, Vec &rhs) noexcept { lhs.swap(rhs); }

  std::array<std::uintptr_t, 3> repr;
};

template <typename T>
Vec<T>::Vec(std::initializer_list<T> init) : Vec{} {
  this->reserve_total(init.size());
  std::move(init.begin(), init.end(), std::back_inserter(*this));
}

template <typename T>
Vec<T>::Vec(const Vec &other) : Vec() {
  this->reserve_total(other.size());
  std::copy(other.begin(), other.end(), std::back_inserter(*this));
}

template <typename T>
Vec<T>::Vec(Vec &&other) noexcept : repr(other.repr) {
  new (&other) Vec();
}

template <typename T>
Vec<T>::~Vec() noexcept {
  this->drop();
}

template <typename T>
Vec<T> &Vec<T>::operator=(Vec &&other) & noexcept {
  this->drop();
  this->repr = other.repr;
  new (&other) Vec();
  return *this;
}

template <typename T>
Vec<T> &Vec<T>::operator=(const Vec &other) & {
  if (this != &other) {
    this->drop();
    new (this) Vec(other);
  }
  return *this;
}

template <typename T>
bool Vec<T>::empty() const noexcept {
  return this->size() == 0;
}

template <typename T>
const T &Vec<T>::operator[](std::size_t n) const noexcept {
  assert(n < this->size());
  auto data = reinterpret_cast<const char *>(this->data());
  return *reinterpret_cast<const T *>(data + n * size_of<T>());
}

template <typename T>
const T &Vec<T>::at(std::size_t n) const {
  if (n >= this->size()) {
    panic<std::out_of_range>("rust::Vec index out of range");
  }
  return (*this)[n];
}

template <typename T>
const T &Vec<T>::front() const noexcept {
  assert(!this->empty());
  return (*this)[0];
}

template <typename T>
const T &Vec<T>::back() const noexcept {
  assert(!this->empty());
  return (*this)[this->size() - 1];
}

template <typename T>
T &Vec<T>::operator[](std::size_t n) noexcept {
  assert(n < this->size());
  auto data = reinterpret_cast<char *>(this->data());
  return *reinterpret_cast<T *>(data + n * size_of<T>());
}

template <typename T>
T &Vec<T>::at(std::size_t n) {
  if (n >= this->size()) {
    panic<std::out_of_range>("rust::Vec index out of range");
  }
  return (*this)[n];
}

template <typename T>
T &Vec<T>::front() noexcept {
  assert(!this->empty());
  return (*this)[0];
}

template <typename T>
T &Vec<T>::back() noexcept {
  assert(!this->empty());
  return (*this)[this->size() - 1];
}

template <typename T>
void Vec<T>::reserve(std::size_t new_cap) {
  this->reserve_total(new_cap);
}

template <typename T>
void Vec<T>::push_back(const T &value) {
  this->emplace_back(value);
}

template <typename T>
void Vec<T>::push_back(T &&value) {
  this->emplace_back(std::move(value));
}

template <typename T>
template <typename... Args>
void Vec<T>::emplace_back(Args &&...args) {
  auto size = this->size();
  this->reserve_total(size + 1);
  ::new (reinterpret_cast<T *>(reinterpret_cast<char *>(this->data()) +
                               size * size_of<T>()))
      T(std::forward<Args>(args)...);
  this->set_len(size + 1);
}

template <typename T>
void Vec<T>::clear() {
  this->truncate(0);
}

template <typename T>
typename Vec<T>::iterator Vec<T>::begin() noexcept {
  return Slice<T>(this->data(), this->size()).begin();
}

template <typename T>
typename Vec<T>::iterator Vec<T>::end() noexcept {
  return Slice<T>(this->data(), this->size()).end();
}

template <typename T>
typename Vec<T>::const_iterator Vec<T>::begin() const noexcept {
  return this->cbegin();
}

template <typename T>
typename Vec<T>::const_iterator Vec<T>::end() const noexcept {
  return this->cend();
}

template <typename T>
typename Vec<T>::const_iterator Vec<T>::cbegin() const noexcept {
  return Slice<const T>(this->data(), this->size()).begin();
}

template <typename T>
typename Vec<T>::const_iterator Vec<T>::cend() const noexcept {
  return Slice<const T>(this->data(), this->size()).end();
}

template <typename T>
void Vec<T>::swap(Vec &rhs) noexcept {
  using std::swap;
  swap(this->repr, rhs.repr);
}

template <typename T>
Vec<T>::Vec(unsafe_bitcopy_t, const Vec &bits) noexcept : repr(bits.repr) {}
#endif // CXXBRIDGE1_RUST_VEC

#ifndef CXXBRIDGE1_RUST_OPAQUE
#define CXXBRIDGE1_RUST_OPAQUE
class Opaque {
public:
  Opaque() = delete;
  Opaque(const Opaque &) = delete;
  ~Opaque() = delete;
};
#endif // CXXBRIDGE1_RUST_OPAQUE

#ifndef CXXBRIDGE1_IS_COMPLETE
#define CXXBRIDGE1_IS_COMPLETE
namespace detail {
namespace {
template <typename T, typename = std::size_t>
struct is_complete : std::false_type {};
template <typename T>
struct is_complete<T, decltype(sizeof(T))> : std::true_type {};
} // namespace
} // namespace detail
#endif // CXXBRIDGE1_IS_COMPLETE

#ifndef CXXBRIDGE1_LAYOUT
#define CXXBRIDGE1_LAYOUT
class layout {
  template <typename T>
  friend std::size_t size_of();
  template <typename T>
  friend std::size_t align_of();
  template <typename T>
  static typename std::enable_if<std::is_base_of<Opaque, T>::value,
                                 std::size_t>::type
  do_size_of() {
    return T::layout::size();
  }
  template <typename T>
  static typename std::enable_if<!std::is_base_of<Opaque, T>::value,
                                 std::size_t>::type
  do_size_of() {
    return sizeof(T);
  }
  template <typename T>
  static
      typename std::enable_if<detail::is_complete<T>::value, std::size_t>::type
      size_of() {
    return do_size_of<T>();
  }
  template <typename T>
  static typename std::enable_if<std::is_base_of<Opaque, T>::value,
                                 std::size_t>::type
  do_align_of() {
    return T::layout::align();
  }
  template <typename T>
  static typename std::enable_if<!std::is_base_of<Opaque, T>::value,
                                 std::size_t>::type
  do_align_of() {
    return alignof(T);
  }
  template <typename T>
  static
      typename std::enable_if<detail::is_complete<T>::value, std::size_t>::type
      align_of() {
    return do_align_of<T>();
  }
};

template <typename T>
std::size_t size_of() {
  return layout::size_of<T>();
}

template <typename T>
std::size_t align_of() {
  return layout::align_of<T>();
}
#endif // CXXBRIDGE1_LAYOUT
} // namespace cxxbridge1
} // namespace rust

#if __cplusplus >= 201402L
#define CXX_DEFAULT_VALUE(value) = value
#else
#define CXX_DEFAULT_VALUE(value)
#endif

namespace diffcassi {
  namespace ffi {
    struct SurfaceInfo;
    struct SpotStats;
    struct DistortionPoint;
    struct DistortionGrid;
    struct RenderOptions;
    enum class RenderPrecision : ::std::uint8_t;
    struct RenderInfo;
    struct PupilPoints;
    struct System;
    struct Rays;
    struct Traced;
    struct Spot;
    struct Mapping;
    struct Jacobian;
  }
}

namespace diffcassi {
namespace ffi {
#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$SurfaceInfo
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$SurfaceInfo
// One row of the resolved Lens Data Editor (pickups and solves evaluated). Lengths mm, angles degrees.
struct SurfaceInfo final {
  ::std::size_t index CXX_DEFAULT_VALUE(0);
  // "Standard", "Even Asphere", "Paraxial", "Coordinate Break".
  ::rust::String kind;
  ::rust::String comment;
  bool is_stop CXX_DEFAULT_VALUE(false);
  // Glass after the surface; empty for air.
  ::rust::String material;
  // Radius of curvature; +infinity for a flat surface (Zemax shows "Infinity").
  double radius_mm CXX_DEFAULT_VALUE(0);
  double thickness_mm CXX_DEFAULT_VALUE(0);
  double conic CXX_DEFAULT_VALUE(0);
  // Paraxial surface focal length (0 for other kinds).
  double focal_length_mm CXX_DEFAULT_VALUE(0);
  // Semi-diameter (given or automatic); `has_semi_diameter` false when unknown (then 0).
  double semi_diameter_mm CXX_DEFAULT_VALUE(0);
  bool has_semi_diameter CXX_DEFAULT_VALUE(false);
  // Coordinate Break decenters and tilts (0 for other kinds), and its order flag.
  double decenter_x_mm CXX_DEFAULT_VALUE(0);
  double decenter_y_mm CXX_DEFAULT_VALUE(0);
  double tilt_x_deg CXX_DEFAULT_VALUE(0);
  double tilt_y_deg CXX_DEFAULT_VALUE(0);
  double tilt_z_deg CXX_DEFAULT_VALUE(0);
  ::std::uint8_t order CXX_DEFAULT_VALUE(0);
  // The surface's local frame origin in global coordinates.
  ::std::array<double, 3> vertex_global_mm;

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$SurfaceInfo

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$SpotStats
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$SpotStats
// Spot statistics about the centroid (`valid` false when no ray arrived; then all 0).
struct SpotStats final {
  bool valid CXX_DEFAULT_VALUE(false);
  ::std::size_t count CXX_DEFAULT_VALUE(0);
  double centroid_x_mm CXX_DEFAULT_VALUE(0);
  double centroid_y_mm CXX_DEFAULT_VALUE(0);
  double rms_radius_um CXX_DEFAULT_VALUE(0);
  double geo_radius_um CXX_DEFAULT_VALUE(0);

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$SpotStats

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionPoint
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionPoint
// One point of a Zemax-style Grid Distortion (see `diffcassi::analysis::DistortionPoint`).
struct DistortionPoint final {
  ::std::int32_t i CXX_DEFAULT_VALUE(0);
  ::std::int32_t j CXX_DEFAULT_VALUE(0);
  double x_field_mm CXX_DEFAULT_VALUE(0);
  double y_field_mm CXX_DEFAULT_VALUE(0);
  double real_x_mm CXX_DEFAULT_VALUE(0);
  double real_y_mm CXX_DEFAULT_VALUE(0);
  double pred_x_mm CXX_DEFAULT_VALUE(0);
  double pred_y_mm CXX_DEFAULT_VALUE(0);
  double distortion_pct CXX_DEFAULT_VALUE(0);
  // `diffcassi::RayStatus` as u8 (0 ok, 1 missed, 2 vignetted, 3 tir, 4 no_convergence, 5 invalid_input).
  ::std::uint8_t status CXX_DEFAULT_VALUE(0);

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionPoint

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionGrid
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionGrid
// A grid distortion at one wavelength.
struct DistortionGrid final {
  double wavelength_nm CXX_DEFAULT_VALUE(0);
  // Image of the on-axis field (Zemax's Xref, Yref), mm.
  ::std::array<double, 2> reference_mm;
  // Predicted-coordinate matrix [A, B, C, D].
  ::std::array<double, 4> abcd;
  double max_distortion_pct CXX_DEFAULT_VALUE(0);
  // n × n points, x-major (Zemax's listing order).
  ::rust::Vec<::diffcassi::ffi::DistortionPoint> points;

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$DistortionGrid

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderOptions
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderOptions
// Render settings (see `render.rs`; `default_render_options()` gives the paper's).
struct RenderOptions final {
  // Spectral planes over the bands' range (0: 4 per band).
  ::std::size_t planes CXX_DEFAULT_VALUE(0);
  ::std::size_t rays_per_pixel CXX_DEFAULT_VALUE(0);
  ::std::uint64_t seed CXX_DEFAULT_VALUE(0);
  double scene_pitch_mm CXX_DEFAULT_VALUE(0);
  double detector_pitch_mm CXX_DEFAULT_VALUE(0);
  // Airy blur, disk diameter in detector pixels at 520 nm (∝ λ).
  bool airy CXX_DEFAULT_VALUE(false);
  double airy_diameter_px CXX_DEFAULT_VALUE(0);
  // Random binary mask used when no mask values are given.
  double mask_opening CXX_DEFAULT_VALUE(0);
  ::std::uint64_t mask_seed CXX_DEFAULT_VALUE(0);
  // An object at infinity: the scene's full angular extent across its width (degrees, in (0, 180);
  // pixels uniform in field angle; `scene_pitch_mm` unused). 0 for a finite object (the default).
  double scene_fov_deg CXX_DEFAULT_VALUE(0);
  // The ray kernel's float precision (`Auto`: f64, or what `tolerance_um` chooses).
  ::diffcassi::ffi::RenderPrecision precision;
  // The error tolerance (µm, image plane) that chooses the backend, the rays per pixel and the
  // precision (the CLI's `--tolerance-um`): 0 for none (the default). With a tolerance,
  // `rays_per_pixel` must be 0, `precision` `Auto` and the backend argument empty.
  double tolerance_um CXX_DEFAULT_VALUE(0);

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderOptions

#ifndef CXXBRIDGE1_ENUM_diffcassi$ffi$RenderPrecision
#define CXXBRIDGE1_ENUM_diffcassi$ffi$RenderPrecision
// A render's float precision: `Auto` (f64 unless a tolerance chooses), or given.
enum class RenderPrecision : ::std::uint8_t {
  Auto = 0,
  F64 = 1,
  F32 = 2,
};
#endif // CXXBRIDGE1_ENUM_diffcassi$ffi$RenderPrecision

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderInfo
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderInfo
// The detector of a render (and, after a render, its ray counts).
struct RenderInfo final {
  ::std::size_t detector_height CXX_DEFAULT_VALUE(0);
  ::std::size_t detector_width CXX_DEFAULT_VALUE(0);
  double detector_pitch_mm CXX_DEFAULT_VALUE(0);
  // x of the left edge of column 0 and y of the top edge of row 0 (mm, image-surface frame).
  double x_left_mm CXX_DEFAULT_VALUE(0);
  double y_top_mm CXX_DEFAULT_VALUE(0);
  ::std::size_t planes CXX_DEFAULT_VALUE(0);
  ::std::uint64_t rays_traced CXX_DEFAULT_VALUE(0);
  ::std::uint64_t rays_arrived CXX_DEFAULT_VALUE(0);
  // What traced the render: the tracer's name as render.json's `tracer` records it (`analytic-f64`,
  // `analytic-f32`, `embree-user…`), the rays per pixel and the precision (`F64` or `F32`): the
  // options' or a tolerance's choice.
  ::rust::String tracer;
  ::std::size_t rays_per_pixel CXX_DEFAULT_VALUE(0);
  ::diffcassi::ffi::RenderPrecision precision;
  // With a tolerance, the error its choice predicts (µm: trace error + σ/√N; render.json's
  // `tolerance_predicted_error_um`); 0 without one.
  double predicted_error_um CXX_DEFAULT_VALUE(0);
  // What the CLI warns about on the same render (and Python raises as UserWarnings): an acquisition
  // that is zero everywhere, planes beyond the scene's bands, a dual disperser's dark planes, the f32
  // kernel's measured rounding. Empty from `render_detector`.
  ::rust::Vec<::rust::String> warnings;

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$RenderInfo

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$PupilPoints
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$PupilPoints
// Normalised pupil points (px, py) of a pattern.
struct PupilPoints final {
  ::rust::Vec<double> px;
  ::rust::Vec<double> py;

  using IsRelocatable = ::std::true_type;
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$PupilPoints

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$System
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$System
// A loaded, immutable, thread-safe system.
struct System final : public ::rust::Opaque {
  ::rust::Str name() const noexcept;
  ::rust::Str description() const noexcept;
  ::rust::Vec<::diffcassi::ffi::SurfaceInfo> surfaces() const noexcept;
  ::std::size_t surface_count() const noexcept;

  // Load-time warnings: glasses whose catalogue contradicts itself, semi-diameters beyond a surface's edge.
  ::rust::Vec<::rust::String> warnings() const noexcept;

  ::std::size_t stop_index() const noexcept;
  ::rust::Slice<double const> wavelengths_nm() const noexcept;
  double primary_wavelength_nm() const noexcept;

  // Field points, interleaved (x0, y0, x1, y1, …), mm.
  ::rust::Vec<double> fields_mm() const noexcept;

  // Ray–surface intersections per traced ray.
  ::std::size_t surfaces_per_ray() const noexcept;

  // The resolved spec in our TOML / JSON format.
  ::rust::String to_toml() const;

  ::rust::String to_json() const;
  ::rust::Box<::diffcassi::ffi::Rays> rays_for_field(double field_x_mm, double field_y_mm, ::rust::Slice<double const> px, ::rust::Slice<double const> py, double wavelength_nm) const;
  ::rust::Box<::diffcassi::ffi::Rays> chief_rays(::rust::Slice<double const> field_x_mm, ::rust::Slice<double const> field_y_mm, double wavelength_nm) const;
  ::rust::Box<::diffcassi::ffi::Rays> seeded_workload(::std::size_t rays_per_wavelength, ::rust::Slice<double const> wavelengths_nm, ::std::uint64_t seed) const;
  ::rust::Box<::diffcassi::ffi::Traced> trace(::rust::Str backend, ::rust::Slice<double const> origin_x, ::rust::Slice<double const> origin_y, ::rust::Slice<double const> origin_z, ::rust::Slice<double const> dir_x, ::rust::Slice<double const> dir_y, ::rust::Slice<double const> dir_z, ::rust::Slice<double const> wavelength_nm) const;

  // Trace library-made rays (no copy either way).
  ::rust::Box<::diffcassi::ffi::Traced> trace_rays(::rust::Str backend, ::diffcassi::ffi::Rays const &rays) const;

  // Bench helper: time `reps` traces of `rays` natively in Rust (no FFI inside the loop); seconds per trace.
  ::rust::Vec<double> time_rust_trace(::rust::Str backend, ::diffcassi::ffi::Rays const &rays, ::std::size_t reps) const;

  ::rust::Box<::diffcassi::ffi::Spot> spot_diagram(::rust::Str backend, double field_x_mm, double field_y_mm, double wavelength_nm, ::rust::Slice<double const> px, ::rust::Slice<double const> py) const;
  ::diffcassi::ffi::DistortionGrid distortion_grid(::rust::Str backend, double wavelength_nm, ::std::size_t n, double half_width_mm) const;
  ::rust::Box<::diffcassi::ffi::Mapping> mapping_cube(::rust::Str backend, ::std::size_t height, ::std::size_t width, double pixel_pitch_mm, ::rust::Slice<double const> wavelengths_nm) const;
  ::rust::Box<::diffcassi::ffi::Jacobian> trace_jacobian(::rust::Str backend, ::rust::Str parameters, ::rust::Slice<double const> origin_x, ::rust::Slice<double const> origin_y, ::rust::Slice<double const> origin_z, ::rust::Slice<double const> dir_x, ::rust::Slice<double const> dir_y, ::rust::Slice<double const> dir_z, ::rust::Slice<double const> wavelength_nm) const;
  ::diffcassi::ffi::RenderInfo render_detector(::rust::Str backend, ::std::size_t height, ::std::size_t width, ::rust::Slice<double const> wavelengths_nm, ::diffcassi::ffi::RenderOptions const &options) const;
  ::diffcassi::ffi::RenderInfo render(::rust::Str backend, ::std::size_t height, ::std::size_t width, ::rust::Slice<double const> wavelengths_nm, ::rust::Slice<float const> scene, ::rust::Slice<float const> mask, ::diffcassi::ffi::RenderOptions const &options, ::rust::Slice<double > out) const;
  ~System() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$System

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$Rays
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$Rays
// Rays made by the library (aimed as the system says); columns viewable from C++.
struct Rays final : public ::rust::Opaque {
  ::std::size_t len() const noexcept;
  ::rust::Slice<double const> origin_x() const noexcept;
  ::rust::Slice<double const> origin_y() const noexcept;
  ::rust::Slice<double const> origin_z() const noexcept;
  ::rust::Slice<double const> dir_x() const noexcept;
  ::rust::Slice<double const> dir_y() const noexcept;
  ::rust::Slice<double const> dir_z() const noexcept;
  ::rust::Slice<double const> wavelength_nm() const noexcept;
  ~Rays() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$Rays

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$Traced
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$Traced
// A traced batch: image-surface positions/directions, status, stop surface per ray.
struct Traced final : public ::rust::Opaque {
  ::std::size_t len() const noexcept;
  ::std::size_t ok_count() const noexcept;
  ::rust::Slice<double const> x() const noexcept;
  ::rust::Slice<double const> y() const noexcept;
  ::rust::Slice<double const> z() const noexcept;
  ::rust::Slice<double const> dir_x() const noexcept;
  ::rust::Slice<double const> dir_y() const noexcept;
  ::rust::Slice<double const> dir_z() const noexcept;
  ::rust::Slice<::std::uint8_t const> status() const noexcept;

  // Surface where a failed ray stopped (`u32::MAX` for arrived rays).
  ::rust::Slice<::std::uint32_t const> surface() const noexcept;

  ~Traced() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$Traced

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$Spot
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$Spot
// A spot diagram.
struct Spot final : public ::rust::Opaque {
  ::std::array<double, 2> field_mm() const noexcept;
  double wavelength_nm() const noexcept;
  ::rust::Slice<double const> x_mm() const noexcept;
  ::rust::Slice<double const> y_mm() const noexcept;
  ::rust::Slice<::std::uint8_t const> status() const noexcept;
  bool has_chief() const noexcept;
  ::std::array<double, 2> chief_mm() const noexcept;
  ::diffcassi::ffi::SpotStats stats() const noexcept;

  // RMS radius about the chief ray (µm; 0 without a chief ray or arrived rays).
  double rms_radius_chief_um() const noexcept;

  ~Spot() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$Spot

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$Mapping
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$Mapping
// A scene → detector mapping cube.
struct Mapping final : public ::rust::Opaque {
  ::std::size_t height() const noexcept;
  ::std::size_t width() const noexcept;
  double pixel_pitch_mm() const noexcept;
  ::rust::Slice<double const> wavelength_nm() const noexcept;

  // Detector (x, y) mm, C order [row][col][λ][xy]; 0 where `valid` is 0.
  ::rust::Slice<double const> positions_mm() const noexcept;

  // 1 where the chief ray arrived, C order [row][col][λ].
  ::rust::Slice<::std::uint8_t const> valid() const noexcept;

  ::std::size_t invalid_count() const noexcept;
  ~Mapping() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$Mapping

#ifndef CXXBRIDGE1_STRUCT_diffcassi$ffi$Jacobian
#define CXXBRIDGE1_STRUCT_diffcassi$ffi$Jacobian
// A batch's Jacobians (SoA, one allocation) with its traced values.
struct Jacobian final : public ::rust::Opaque {
  ::std::size_t len() const noexcept;
  ::std::size_t parameter_count() const noexcept;
  ::rust::Vec<::rust::String> parameters() const noexcept;
  ::rust::Slice<double const> values() const noexcept;
  ::rust::Slice<::std::uint8_t const> available() const noexcept;
  ::rust::Str reason(::std::size_t i) const noexcept;
  ::rust::Slice<double const> traced_x() const noexcept;
  ::rust::Slice<double const> traced_y() const noexcept;
  ::rust::Slice<double const> traced_z() const noexcept;
  ::rust::Slice<double const> traced_dir_x() const noexcept;
  ::rust::Slice<double const> traced_dir_y() const noexcept;
  ::rust::Slice<double const> traced_dir_z() const noexcept;
  ::rust::Slice<::std::uint8_t const> traced_status() const noexcept;
  ~Jacobian() = delete;

private:
  friend ::rust::layout;
  struct layout {
    static ::std::size_t size() noexcept;
    static ::std::size_t align() noexcept;
  };
};
#endif // CXXBRIDGE1_STRUCT_diffcassi$ffi$Jacobian

::rust::Box<::diffcassi::ffi::System> load_preset(::rust::Str name);

// `.toml`, `.json` (our format), `.yml` (the paper's), `.csv` (Zemax prescription).
::rust::Box<::diffcassi::ffi::System> load_spec_file(::rust::Str path);

// `format`: "toml", "json" or "auto" (JSON if the text starts with `{`, after blanks and a byte-order mark); `source_name` names the
// text in error messages.
::rust::Box<::diffcassi::ffi::System> load_spec_string(::rust::Str text, ::rust::Str format, ::rust::Str source_name);

::rust::Vec<::rust::String> preset_names() noexcept;

// Every backend name `trace` accepts (some may be unavailable in this build).
::rust::Vec<::rust::String> backend_names() noexcept;

::rust::String version() noexcept;

// `chief`, `marginal`, `hexapolar:R`, `grid:N`, `grid-step:S`, `random:N:SEED`.
::diffcassi::ffi::PupilPoints pupil_points(::rust::Str pattern);

// The learned denoiser on a cube [row][col][band] f32 into `out` (same size); `weights` empty: embedded.
void denoise(::rust::Slice<float const> cube, ::std::size_t height, ::std::size_t width, ::std::size_t bands, double sigma, ::rust::Str weights, ::rust::Slice<float > out);

// `count` evenly spaced values from `first` to `last` (inclusive).
::rust::Vec<double> linspace(double first, double last, ::std::size_t count);

::diffcassi::ffi::RenderOptions default_render_options() noexcept;

// The memory and ray budgets of every following call (`has_…` false: the default).
void set_limits(bool has_memory, double max_memory_gb, bool has_rays, double max_rays);

// The threads of every following call (0: all cores or `RAYON_NUM_THREADS`; at most 1024).
void set_num_threads(::std::size_t n);

// The threads the following calls use.
::std::size_t get_num_threads();

// The folder of the render tolerance's calibration cache (the CLI's `--calibration-cache`) for every
// following call; empty: the default (`$DIFFCASSI_CACHE_DIR`, `$XDG_CACHE_HOME/diffcassi`,
// `~/.cache/diffcassi`). A path that exists and is not a folder is refused.
void set_calibration_cache(::rust::Str dir);
} // namespace ffi
} // namespace diffcassi

#ifdef __clang__
#pragma clang diagnostic pop
#endif // __clang__
