// EIPScanner (github.com/nimbuscontrols/EIPScanner, MIT) as a class-1 originator against one farm
// device, for bench/real_scanners.py: its ConnectionManager opens an exclusive-owner connection
// (config 1, O->T assembly 100 with a run/idle header, T->O 101, 2 bytes each way, as a DSQC1030
// has them) at the RPI given, drives it with handleConnections(1 ms) as its example does (with 100
// ms there) for the seconds given, then Forward Closes it; timeout multiplier 2 (16 RPI). Only this driver is the project's; the
// bench builds it against an EIPScanner source tree and build directory given to it:
//
//     g++ -O2 -std=c++20 -I SRC/src -o eipscanner_originator bench/eipscanner_originator.cpp BUILD/src/libEIPScannerS.a
//
//     eipscanner_originator HOST RPI_US SECONDS
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <vector>

#include "ConnectionManager.h"
#include "SessionInfo.h"
#include "cip/connectionManager/NetworkConnectionParams.h"
#include "utils/Logger.h"

using eipScanner::ConnectionManager;
using eipScanner::SessionInfo;
using eipScanner::cip::connectionManager::ConnectionParameters;
using eipScanner::cip::connectionManager::NetworkConnectionParams;
using eipScanner::utils::Logger;
using eipScanner::utils::LogLevel;

int main(int argc, char **argv) {
  if (argc != 4) {
    std::cerr << "usage: eipscanner_originator HOST RPI_US SECONDS\n";
    return 2;
  }
  Logger::setLogLevel(LogLevel::WARNING);
  const std::string host = argv[1];
  const unsigned rpi = std::strtoul(argv[2], nullptr, 10);
  const double seconds = std::atof(argv[3]);
  auto si = std::make_shared<SessionInfo>(host, 0xAF12);
  ConnectionManager manager;
  ConnectionParameters parameters;
  parameters.connectionPath = {0x20, 0x04, 0x24, 0x01, 0x2C, 0x64, 0x2C, 0x65};
  parameters.o2tRealTimeFormat = true;
  parameters.originatorVendorId = 342;
  parameters.originatorSerialNumber = 0x12345;
  parameters.t2oNetworkConnectionParams |= NetworkConnectionParams::P2P;
  parameters.t2oNetworkConnectionParams |= NetworkConnectionParams::SCHEDULED_PRIORITY;
  parameters.t2oNetworkConnectionParams |= 2;  // data bytes: the library adds the sequence count
  parameters.o2tNetworkConnectionParams |= NetworkConnectionParams::P2P;
  parameters.o2tNetworkConnectionParams |= NetworkConnectionParams::SCHEDULED_PRIORITY;
  parameters.o2tNetworkConnectionParams |= 2;  // data bytes: the library adds the count and the header
  parameters.o2tRPI = rpi;
  parameters.t2oRPI = rpi;
  parameters.transportTypeTrigger |= NetworkConnectionParams::CLASS1;
  parameters.connectionTimeoutMultiplier = 2;  // 16 RPI, as the other scanners ask (its default 0: 4 RPI)
  auto io = manager.forwardOpen(si, parameters);
  auto connection = io.lock();
  if (!connection) {
    std::cerr << "Forward Open refused\n";
    return 1;
  }
  connection->setDataToSend(std::vector<uint8_t>(2));
  std::cout << "open" << std::endl;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (manager.hasOpenConnections() && std::chrono::steady_clock::now() < end) {
    manager.handleConnections(std::chrono::milliseconds(1));
  }
  manager.forwardClose(si, io);
  std::cout << "closed" << std::endl;
  return 0;
}
