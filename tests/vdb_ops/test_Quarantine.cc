// The child process that runs a reader library (vdb_ops/src/Quarantine.h; docs/hardening.md
// "Quarantine"): whatever the child does (answers, fails, prints, aborts, dereferences null,
// hangs), the parent gets an answer, one InputError line or an InterruptedError, and no child
// is left behind.
#include "Quarantine.h"

#include <isouq/Errors.h>

#include <catch2/catch.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <thread>

using isouq::sources_internal::Message;
using isouq::sources_internal::Quarantine;
using Catch::Matchers::Contains;

namespace {

/// What the child does with a request: its first value.
enum Act : int { kEcho, kFail, kAbort, kNull, kHang, kHuge };

Message serve(Message& request)
{
    switch (request.get<int>()) {
    case kEcho: return Message().putString("echo " + request.getString());
    case kFail:
        std::fprintf(stderr, "lib: bad\nthing\n");
        throw isouq::InputError("'f.dcm' is not readable");
    case kAbort: std::abort();
    case kNull: {
        volatile int* volatile nowhere = nullptr;
        *nowhere = 1;
        break;
    }
    case kHang:
        for (;;) ::pause();
    case kHuge: return Message(std::string(1 << 20, 'x'));
    }
    return Message();
}

Message ask(Quarantine& child, int act, std::uint64_t maxReply = 1024, openvdb::util::NullInterrupter* interrupter = nullptr)
{
    Message request;
    request.put(act).putString("hello");
    return child.call(request, "f.dcm", maxReply, interrupter);
}

/// Interrupted from @a after on.
struct LateInterrupter : openvdb::util::NullInterrupter {
    std::chrono::steady_clock::time_point at;
    explicit LateInterrupter(std::chrono::milliseconds after) : at(std::chrono::steady_clock::now() + after) {}
    bool wasInterrupted(int = -1) override { return std::chrono::steady_clock::now() >= at; }
};

bool noChildLeft() { return ::waitpid(-1, nullptr, WNOHANG) == -1 && errno == ECHILD; }

} // namespace

TEST_CASE("Quarantine: answers come back, one request after another", "[quarantine]")
{
    {
        Quarantine child("LIB", serve);
        for (int k = 0; k < 3; ++k) CHECK(ask(child, kEcho).getString() == "echo hello");
    }
    CHECK(noChildLeft());
}

TEST_CASE("Quarantine: a failure is the child's one line, with what the library printed", "[quarantine]")
{
    Quarantine child("LIB", serve);
    try {
        ask(child, kFail);
        FAIL("no error");
    } catch (const isouq::InputError& e) {
        CHECK(std::string(e.what()) == "'f.dcm' is not readable (LIB says: lib: bad thing)");
    }
    // The child goes on serving, and forgot what was printed for the failed request.
    CHECK(ask(child, kEcho).getString() == "echo hello");
}

TEST_CASE("Quarantine: an abort or a SIGSEGV in the child is an InputError here", "[quarantine]")
{
    for (const int act : {kAbort, kNull}) {
        {
            Quarantine child("LIB", serve);
            std::string error;
            try {
                ask(child, act);
            } catch (const isouq::InputError& e) {
                error = e.what();
            }
            INFO(error);
            // Under AddressSanitizer a SIGSEGV is its report and exit status 1 instead.
            CHECK_THAT(error, Contains("'f.dcm' crashed LIB ("));
            if (act == kAbort) CHECK_THAT(error, Contains("(SIGABRT, Aborted)"));
            else CHECK_THAT(error, Contains("(SIGSEGV, Segmentation fault)") || Contains("exited with status 1"));
            CHECK(error.find('\n') == std::string::npos);
            CHECK_THROWS_WITH(ask(child, kEcho), Contains("has stopped"));
        }
        CHECK(noChildLeft());
    }
}

TEST_CASE("Quarantine: an interrupter stops a child that hangs within a second", "[quarantine]")
{
    {
        Quarantine child("LIB", serve);
        LateInterrupter interrupter(std::chrono::milliseconds(200));
        const auto start = std::chrono::steady_clock::now();
        CHECK_THROWS_AS(ask(child, kHang, 1024, &interrupter), isouq::InterruptedError);
        CHECK(std::chrono::steady_clock::now() - start < std::chrono::seconds(1));
    }
    CHECK(noChildLeft());
}

TEST_CASE("Quarantine: an answer longer than expected is refused", "[quarantine]")
{
    Quarantine child("LIB", serve);
    CHECK_THROWS_WITH(ask(child, kHuge, 4096), Contains("gave 1048577 bytes where at most 4096 were expected"));
    // The stream is out of step after a refused answer: the child is gone.
    CHECK_THROWS_WITH(ask(child, kEcho), Contains("has stopped"));
    Quarantine second("LIB", serve);
    CHECK(ask(second, kHuge, 2 << 20).left() == std::size_t(1 << 20));
}
