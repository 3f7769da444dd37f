// Starts a real hvdb-server binary on an ephemeral loopback port for a test, and stops it.
#ifndef HVDB_TESTS_SERVER_SERVER_PROCESS_H_
#define HVDB_TESTS_SERVER_SERVER_PROCESS_H_

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

namespace hvdb::testing {

class ServerProcess {
 public:
  // Starts HVDB_SERVER_PATH with --data dir --listen 127.0.0.1:0 and the extra arguments.
  ServerProcess(const std::string& data_dir, std::vector<std::string> extra = {},
                const std::string& listen = "127.0.0.1:0") {
    port_file_ = data_dir + ".port";
    ::unlink(port_file_.c_str());
    std::vector<std::string> args = {HVDB_SERVER_PATH, "--data", data_dir, "--listen",
                                     listen, "--port-file", port_file_,
                                     "--log-level", "warn"};
    args.insert(args.end(), extra.begin(), extra.end());
    pid_ = ::fork();
    if (pid_ == 0) {
      int devnull = ::open("/dev/null", O_WRONLY);
      ::dup2(devnull, STDOUT_FILENO);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
    for (int i = 0; i < 500 && port_ == 0; ++i) {
      std::ifstream in(port_file_);
      int p = 0;
      if (in >> p && p > 0) port_ = static_cast<uint16_t>(p);
      int h = 0;  // with --http, the web port on a second line (the file is written whole)
      if (port_ != 0 && in >> h && h > 0) http_port_ = static_cast<uint16_t>(h);
      if (port_ == 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
      int status;
      if (port_ == 0 && ::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        exit_status_ = status;
        return;
      }
    }
  }
  ~ServerProcess() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  uint16_t port() const { return port_; }
  uint16_t http_port() const { return http_port_; }
  pid_t pid() const { return pid_; }
  bool running() const { return pid_ > 0 && port_ != 0; }
  // Sends `sig` and waits; returns the wait status.
  int Stop(int sig) {
    if (pid_ <= 0) return exit_status_;
    ::kill(pid_, sig);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return status;
  }
  // Resident memory of the server process in KiB.
  long RssKib() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string key;
    long value = 0;
    while (in >> key) {
      if (key == "VmRSS:") {
        in >> value;
        return value;
      }
    }
    return -1;
  }

 private:
  std::string port_file_;
  pid_t pid_ = -1;
  uint16_t port_ = 0;
  uint16_t http_port_ = 0;
  int exit_status_ = 0;
};

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_SERVER_SERVER_PROCESS_H_
