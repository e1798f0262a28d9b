#pragma once
// SOFTDIFF_DEMAND(cond, msg): always checked (programming errors at API entry
// points: sizes, indices); throws std::logic_error with file:line.
// SOFTDIFF_ASSERT(cond): checked in debug builds only (hot loops).
#include <stdexcept>
#include <string>

#define SOFTDIFF_STRINGIFY2(x) #x
#define SOFTDIFF_STRINGIFY(x) SOFTDIFF_STRINGIFY2(x)
#define SOFTDIFF_DEMAND(cond, msg)                                                          \
  do {                                                                                      \
    if (!(cond))                                                                            \
      throw std::logic_error(std::string(__FILE__ ":" SOFTDIFF_STRINGIFY(__LINE__) ": ") + \
                             "check failed: " #cond ": " + (msg));                          \
  } while (0)
#ifdef NDEBUG
#define SOFTDIFF_ASSERT(cond) ((void)0)
#else
#define SOFTDIFF_ASSERT(cond) SOFTDIFF_DEMAND(cond, "assertion")
#endif
