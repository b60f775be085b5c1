// isouq: a reader library in a child process (Quarantine.h; docs/hardening.md "Quarantine").
// The child is forked from whatever thread asks (the CLI, a Python thread, Blender), so it only
// runs the library's calls and leaves with _exit: no atexit handlers (Open MPI's, the leak
// checker's), no flush of the parent's stdio buffers.
#include "Quarantine.h"
#include "SourcesInternal.h"

#include "isouq/Errors.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>

namespace isouq::sources_internal {
namespace {

/// Sends all of @a n bytes; false when the other side is gone.
bool sendAll(int fd, const char* data, std::size_t n)
{
    while (n > 0) {
        const ssize_t sent = ::send(fd, data, n, MSG_NOSIGNAL);
        if (sent < 0 && errno == EINTR) continue;
        if (sent <= 0) return false;
        data += sent;
        n -= std::size_t(sent);
    }
    return true;
}

bool sendMessage(int fd, char tag, const std::string& bytes)
{
    const std::uint64_t length = bytes.size() + 1;
    return sendAll(fd, reinterpret_cast<const char*>(&length), sizeof length) && sendAll(fd, &tag, 1)
        && sendAll(fd, bytes.data(), bytes.size());
}

/// Receives exactly @a n bytes, waking every 100 ms to ask @a stopped; false at end of stream.
template <typename Stopped> bool receiveAll(int fd, char* data, std::size_t n, const Stopped& stopped)
{
    while (n > 0) {
        pollfd p{fd, POLLIN, 0};
        const int ready = ::poll(&p, 1, 100);
        stopped();
        if (ready <= 0) continue; // timeout, or EINTR from the CLI's signal handler
        const ssize_t got = ::recv(fd, data, n, 0);
        if (got < 0 && errno == EINTR) continue;
        if (got <= 0) return false;
        data += got;
        n -= std::size_t(got);
    }
    return true;
}

/// What the child printed to its stderr (a memory file) since @a fd was last emptied.
std::string printed(int fd)
{
    char buf[kPrintedChars];
    const ssize_t n = ::pread(fd, buf, sizeof buf, 0);
    return printedLine(std::string_view(buf, n > 0 ? std::size_t(n) : 0));
}

} // namespace

Quarantine::Quarantine(std::string library, Serve serve) : mLibrary(std::move(library))
{
    int sockets[2];
    if (::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sockets) != 0)
        throw IoError("cannot start a process for " + mLibrary + ": " + std::strerror(errno));
    std::fflush(nullptr);
    const pid_t parent = ::getpid();
    mChild = ::fork();
    if (mChild < 0) {
        const int error = errno;
        ::close(sockets[0]);
        ::close(sockets[1]);
        throw IoError("cannot start a process for " + mLibrary + ": " + std::strerror(error));
    }
    if (mChild == 0) {
        ::close(sockets[0]);
        mSocket = sockets[1];
        // Gone with the parent, even when it is killed; quiet when it crashes itself.
        ::prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (::getppid() != parent) ::_exit(0);
        childMain(serve);
    }
    ::close(sockets[1]);
    mSocket = sockets[0];
}

Quarantine::~Quarantine() { stop(); }

void Quarantine::stop()
{
    if (mSocket >= 0) ::close(mSocket);
    mSocket = -1;
    if (mChild > 0) {
        ::kill(mChild, SIGKILL);
        while (::waitpid(mChild, nullptr, 0) < 0 && errno == EINTR) {}
    }
    mChild = -1;
}

void Quarantine::childMain(const Serve& serve)
{
    // The parent's signal handlers (the CLI's, libFuzzer's, the sanitizers') are not for the
    // child: a terminal's Ctrl-C reaches the whole process group and the parent decides; a
    // crash ends the child at once, without a core file.
    for (int sig : {SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGPIPE}) ::signal(sig, SIG_IGN);
    for (int sig : {SIGSEGV, SIGBUS, SIGABRT, SIGFPE, SIGILL, SIGSYS}) ::signal(sig, SIG_DFL);
    const rlimit noCore{0, 0};
    ::setrlimit(RLIMIT_CORE, &noCore);
    // What the library prints (libjpeg's messages from GDCM's trial decoders) goes to a memory
    // file, read back into the error message of a failed request.
    int err = ::memfd_create("isouq-stderr", MFD_CLOEXEC);
    if (err < 0) err = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    if (err >= 0) ::dup2(err, 2);
    const auto never = [] {};
    for (;;) {
        std::uint64_t length = 0;
        if (!receiveAll(mSocket, reinterpret_cast<char*>(&length), sizeof length, never)) ::_exit(0);
        std::string bytes(std::size_t(length), '\0');
        if (!receiveAll(mSocket, bytes.data(), bytes.size(), never)) ::_exit(0);
        if (err >= 0 && ::ftruncate(2, 0) == 0) ::lseek(2, 0, SEEK_SET);
        bool sent;
        try {
            Message request(std::move(bytes));
            sent = sendMessage(mSocket, 'K', serve(request).bytes());
        } catch (const std::exception& e) {
            const std::string said = err >= 0 ? printed(2) : std::string();
            sent = sendMessage(mSocket, 'E', e.what() + (said.empty() ? "" : " (" + mLibrary + " says: " + said + ")"));
        } catch (...) {
            sent = sendMessage(mSocket, 'E', mLibrary + " failed without a message");
        }
        if (!sent) ::_exit(0);
    }
}

void Quarantine::died(const std::string& subject)
{
    int status = 0;
    pid_t waited;
    while ((waited = ::waitpid(mChild, &status, 0)) < 0 && errno == EINTR) {}
    mChild = -1;
    stop();
    std::string how = "it stopped";
    if (waited > 0 && WIFSIGNALED(status)) {
        const char* name = ::sigabbrev_np(WTERMSIG(status));
        how = std::string("SIG") + (name ? name : std::to_string(WTERMSIG(status)).c_str()) + ", "
            + ::strsignal(WTERMSIG(status));
    } else if (waited > 0 && WIFEXITED(status)) {
        how = "it exited with status " + std::to_string(WEXITSTATUS(status));
    }
    throw InputError("'" + subject + "' crashed " + mLibrary + " (" + how
        + "); the file is damaged or made to break it, and isouq read it in a separate process");
}

Message Quarantine::call(const Message& request, const std::string& subject, std::uint64_t maxReply,
    openvdb::util::NullInterrupter* interrupter)
{
    std::lock_guard<std::mutex> lock(mCall);
    if (mChild <= 0) throw InputError("the process reading with " + mLibrary + " has stopped");
    const std::uint64_t length = request.bytes().size();
    if (!sendAll(mSocket, reinterpret_cast<const char*>(&length), sizeof length)
        || !sendAll(mSocket, request.bytes().data(), request.bytes().size()))
        died(subject);
    const auto stopped = [&] {
        if (openvdb::util::wasInterrupted(interrupter)) {
            stop();
            throw InterruptedError();
        }
    };
    std::uint64_t replyLength = 0;
    if (!receiveAll(mSocket, reinterpret_cast<char*>(&replyLength), sizeof replyLength, stopped)) died(subject);
    // An error's message may be longer than the largest answer expected.
    if (replyLength == 0 || replyLength > std::max<std::uint64_t>(maxReply, 1 << 16) + 1) {
        stop();
        throw InputError("reading '" + subject + "', " + mLibrary + " gave " + std::to_string(replyLength)
            + " bytes where at most " + std::to_string(maxReply) + " were expected");
    }
    std::string reply(std::size_t(replyLength), '\0');
    if (!receiveAll(mSocket, reply.data(), reply.size(), stopped)) died(subject);
    Message answer(std::move(reply));
    if (answer.get<char>() == 'E') throw InputError(std::string(answer.rest(), answer.left()));
    return answer;
}

} // namespace isouq::sources_internal
