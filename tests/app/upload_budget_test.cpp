// UploadBudget: reservations fit or are refused, come back when released (also moved, reset or
// outliving the budget), and one larger than the whole budget may run alone.
#include "app/upload_budget.h"

#include <gtest/gtest.h>

#include <optional>
#include <thread>
#include <utility>
#include <vector>

namespace octoscope::app {
namespace {

TEST(UploadBudgetTest, ReservationsFitOrAreRefusedAndComeBackWhenReleased) {
  UploadBudget budget(100);
  auto a = budget.TryReserve(60);
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->bytes(), 60u);
  EXPECT_FALSE(budget.TryReserve(41).has_value());
  auto b = budget.TryReserve(40);
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(budget.reserved(), 100u);
  EXPECT_TRUE(budget.TryReserve(0).has_value());  // Nothing always fits.
  a->reset();
  EXPECT_EQ(budget.reserved(), 40u);
  a->reset();  // Idempotent.
  EXPECT_EQ(budget.reserved(), 40u);
  // Moved: released once, by the last owner.
  UploadBudget::Reservation moved = std::move(*b);
  b.reset();
  EXPECT_EQ(budget.reserved(), 40u);
  moved = UploadBudget::Reservation();
  EXPECT_EQ(budget.reserved(), 0u);
}

TEST(UploadBudgetTest, AnUploadLargerThanTheBudgetRunsAlone) {
  UploadBudget budget(100);
  auto alone = budget.TryReserve(250);
  ASSERT_TRUE(alone.has_value());
  EXPECT_EQ(alone->bytes(), 100u);
  EXPECT_FALSE(budget.TryReserve(1).has_value());
  alone->reset();
  EXPECT_TRUE(budget.TryReserve(250).has_value());
}

TEST(UploadBudgetTest, ReservationsMayOutliveTheBudgetAndComeFromManyThreads) {
  std::optional<UploadBudget::Reservation> kept;
  {
    UploadBudget budget(1000);
    std::vector<std::thread> threads;
    for (int t = 0; t < 8; ++t) {
      threads.emplace_back([&] {
        for (int i = 0; i < 10000; ++i) {
          auto r = budget.TryReserve(100);
          if (r) {
            EXPECT_LE(budget.reserved(), 1000u);
          }
        }
      });
    }
    for (auto& t : threads) t.join();
    EXPECT_EQ(budget.reserved(), 0u);
    kept = budget.TryReserve(10);
  }
  kept.reset();  // The budget is gone; releasing is still safe.
}

}  // namespace
}  // namespace octoscope::app
