// isouq (internal): a reader library that may crash on a hostile file runs in a child process
// (docs/hardening.md "Quarantine"). Debian's GDCM keeps its assertions and has wild writes in
// its JPEG 2000 codec (fuzz_dicom); in a child, its abort or SIGSEGV becomes one InputError
// line here (SPEC §8: one line, exit 2) instead of the end of the CLI, the Python interpreter or
// Blender.
#pragma once

#include "isouq/Errors.h"

#include <openvdb/util/NullInterrupter.h>

#include <sys/types.h>

#include <cstdint>
#include <cstring>
#include <functional>
#include <mutex>
#include <string>
#include <type_traits>

namespace isouq::sources_internal {

/// A message between the parent and the child: values appended as bytes, read back in order.
class Message {
public:
    Message() = default;
    explicit Message(std::string bytes) : mBytes(std::move(bytes)) {}

    template <typename T> Message& put(const T& value)
    {
        static_assert(std::is_trivially_copyable_v<T>);
        mBytes.append(reinterpret_cast<const char*>(&value), sizeof(T));
        return *this;
    }
    Message& putString(const std::string& s)
    {
        put(std::uint64_t(s.size()));
        mBytes += s;
        return *this;
    }
    /// @throw InputError when the message ends before the value.
    template <typename T> T get()
    {
        static_assert(std::is_trivially_copyable_v<T>);
        T value;
        std::memcpy(&value, take(sizeof(T)), sizeof(T));
        return value;
    }
    std::string getString()
    {
        const auto n = get<std::uint64_t>();
        return std::string(take(n), std::size_t(n));
    }
    /// The bytes not read yet (the pixels at the end of a reply).
    std::size_t left() const { return mBytes.size() - mRead; }
    const char* rest() const { return mBytes.data() + mRead; }
    const std::string& bytes() const { return mBytes; }

private:
    const char* take(std::uint64_t n)
    {
        if (n > left()) throw InputError("a message from a reader process ends early");
        const char* at = mBytes.data() + mRead;
        mRead += std::size_t(n);
        return at;
    }
    std::string mBytes;
    std::size_t mRead = 0;
};

/// A child process forked at construction that answers requests with @a serve until this
/// object dies. serve may throw InputError: its message (with what the library printed to
/// stderr meanwhile, as "(LIBRARY says: ...)") is thrown again by call(). If the child dies,
/// call() throws InputError "'SUBJECT' crashed LIBRARY (SIGSEGV, ...)"; an interrupter that
/// fires while the child works kills it and throws InterruptedError. One call at a time.
class Quarantine {
public:
    using Serve = std::function<Message(Message&)>;
    Quarantine(std::string library, Serve serve);
    ~Quarantine();
    Quarantine(const Quarantine&) = delete;
    Quarantine& operator=(const Quarantine&) = delete;

    /// @a subject names the file the request is about, for the crash message; a reply longer
    /// than @a maxReply bytes (or 64 KiB, for an error's message) is refused.
    Message call(const Message& request, const std::string& subject, std::uint64_t maxReply,
        openvdb::util::NullInterrupter* interrupter);

private:
    [[noreturn]] void childMain(const Serve& serve);
    [[noreturn]] void died(const std::string& subject);
    void stop(); ///< closes the socket, kills a live child and waits for it

    std::string mLibrary;
    std::mutex mCall;
    int mSocket = -1;
    pid_t mChild = -1;
};

} // namespace isouq::sources_internal
